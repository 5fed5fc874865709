"""A run's outputs: trajectory.npz, summary.json, the figures and the report printed at the
end (:func:`write_outputs`), and the recording's fields (:func:`recording_fields`)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from apf_swarm_core.config import SwarmConfig

from ..analysis.samples import StateAccumulator
from .commands import Plan

__all__ = ['recording_fields', 'write_outputs']


def write_outputs(
    *,
    plan: Plan,
    cfg: SwarmConfig,
    acc: StateAccumulator,
    fields: dict[str, Any],
    judged: Callable[[dict[str, Any]], dict[str, Any]] | None,
    say: Callable[[str], None],
) -> None:
    """Write and print the run's outputs: ``fields`` (the bring-up's) join the summary;
    ``judged`` (realtime) judges the trajectory; ``cfg``: the configuration flown."""
    from ..analysis.runio import format_summary, run_summary, write_run

    out, status = plan.out, fields['status']
    traj = acc.trajectory()
    if traj is None:
        say(
            f'no /swarm/state samples: wrote no trajectory.npz / summary.json '
            f'(config and logs are in {out})'
        )
        return
    summary = run_summary(
        traj,
        cfg,
        status=status,
        n_samples=len(acc.samples),
        dropped=acc.dropped,
        respawned=list(fields['respawned']),
    )
    summary.update(fields)
    if judged is not None:
        summary['flight_check'] = judged(traj)
    paths = write_run(out, traj, summary, cfg)
    if not plan.no_plots and len(traj['t']) > 1:
        from ..analysis import plots

        title = f'{cfg.law} law, ROS 2 {plan.mode} run'
        for key, plot, what in (
            ('trajectories_3d', plots.plot_trajectories_3d, 'trajectories'),
            ('xy_time', plots.plot_xy_time, 'x and y'),
            ('centroid', plots.plot_centroid, 'formation centre'),
        ):
            paths[key] = plot(traj, f'{what}, {title}', out / f'{key}.png')
        paths['centroid_error'] = plots.plot_centroid_error(
            {cfg.law: traj},
            f'centroid error, ROS 2 {plan.mode} run',
            out / 'centroid_error.png',
        )
    print(format_summary(summary))
    pr = summary.get('flight_check')
    if pr is not None:
        from apf_swarm_core.metrics import flight_verdict as verdict

        print(f'  flight           run {verdict(pr["run"])}')
        if 'emulation' in pr:
            print(
                f"  headless         {verdict(pr['emulation'])} (same rate, the run's own "
                f'delays replayed: p50 {1e3 * pr["latency"]["p50"]:.2g} ms, p99 '
                f'{1e3 * pr["latency"]["p99"]:.2g} ms)'
            )
    m = summary['messages']
    print(
        f'  run              {status}, {plan.mode}, ROS_DOMAIN_ID {fields["domain_id"]}, '
        f'{summary["wall_time"]:g} s wall, {m["received"]} messages, {m["dropped"]} '
        f'dropped, missed deadlines {summary["missed_deadlines"]}, stale '
        f'{summary["stale_inputs"]}, rejected {summary["rejected_inputs"]}, respawns '
        f'{summary["respawns"]}'
    )
    rec = summary.get('recording')
    if rec is not None:
        print(
            f'  recording        {rec["bag"]}: '
            + (
                rec['error']
                if 'error' in rec
                else f'{rec["messages"]} messages on {rec["topics"]} topics, received '
                f'{rec["received"]}, written {rec["written"]}, dropped {rec["dropped"]}'
            )
        )
    figs = [p.name for p in paths.values() if p.suffix == '.png']
    print(
        f'wrote {out / "trajectory.npz"}, {out / "summary.json"}'
        + (f' and {", ".join(figs)}' if figs else '')
    )


def recording_fields(bag: Path) -> dict[str, Any]:
    """summary.json ``recording``: the bag and the recorder's counts (its metadata.yaml)."""
    import json

    import yaml

    out: dict[str, Any] = {'bag': str(bag)}
    try:
        meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        out['error'] = (
            f'no readable {bag / "metadata.yaml"} (the recorder did not close the '
            f'bag); `apf-swarm bag reindex {bag}` recovers its flushed chunks'
        )
        return out
    out['messages'] = int(meta.get('message_count', 0))
    out['topics'] = len(meta.get('topics_with_message_count') or [])
    try:
        counts = json.loads((meta.get('custom_data') or {}).get('apf_swarm.recorder', '{}'))
    except ValueError:
        counts = {}
    for key in ('received', 'written', 'lost', 'dropped'):
        out[key] = counts.get(key)
    return out
