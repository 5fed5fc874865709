"""A run's outputs: the run's fields of summary.json, trajectory.npz, summary.json, the
figures and the report printed at the end."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from apf_swarm_core.config import (
    SwarmConfig,
)

from ..analysis.samples import StateAccumulator
from .graph import (
    recording_fields,
)
from .processes import (
    ProcessGroup,
    describe_rc,
)


class RunOutputs:
    """What :class:`~.session.Bringup` writes and prints at the end of a run (a mixin)."""

    args: argparse.Namespace
    cfg: SwarmConfig
    mode: str
    out: Path
    acc: StateAccumulator
    group: ProcessGroup
    domain_id: int | None
    run_id: int
    t_begin: float
    t_launch: Any
    t_start: Any
    t_end: Any
    stop_how: dict[str, str]
    stop_seconds: float
    recorder_lost: dict[str, int]
    prediction: Any

    def say(self, text: str) -> None:
        raise NotImplementedError

    def predicted(self, traj: dict[str, Any]) -> dict[str, Any]:
        raise NotImplementedError

    def run_fields(self, status: str) -> dict[str, Any]:
        last = self.acc.last
        run_s = (self.t_end - self.t_start) if self.t_start is not None else 0.0
        return {
            'status': status,
            'mode': self.mode,
            'domain_id': self.domain_id,
            'run_id': f'{self.run_id:x}',
            'wall_time': round(run_s, 3),
            'missed_deadlines': int(last.missed_deadlines) if last is not None else 0,
            'stale_inputs': int(last.stale_inputs) if last is not None else 0,
            'rejected_inputs': int(last.rejected_inputs) if last is not None else 0,
            'respawns': sum(c.respawns for c in self.group),
            'respawned': {c.name: c.respawns for c in self.group if c.respawns},
            'messages': self.acc.messages(),
            'timing': {
                'ready': round(self.t_start - self.t_launch, 3)
                if self.t_start is not None and self.t_launch is not None
                else None,
                # the bring-up's own start to graph ready (preparation, isolation included)
                'startup': round(self.t_start - self.t_begin, 3)
                if self.t_start is not None
                else None,
                'run': round(run_s, 3),
                'shutdown': round(self.stop_seconds, 3),
                'rate': round(len(self.acc.samples) / run_s, 1) if run_s > 0 else None,
            },
            'stopped_by': self.stop_how,
            # how many needed which signal: SIGKILL is the exception (a node that never left
            # DDS leaves shared memory behind, which the bring-up then removes)
            'stop_signals': {
                how: sum(1 for v in self.stop_how.values() if v == how)
                for how in sorted(set(self.stop_how.values()))
            },
            **(
                {
                    'recording': {
                        **recording_fields(self.out / 'bag'),
                        **(
                            {'recorder_died': describe_rc(list(self.recorder_lost.values())[-1])}
                            if self.recorder_lost
                            else {}
                        ),
                    }
                }
                if self.args.record
                else {}
            ),
        }

    def write_outputs(self, status: str) -> dict[str, Path]:
        from ..analysis.runio import format_summary, run_summary, write_run

        traj = self.acc.trajectory()
        if traj is None:
            self.say(
                f'no /swarm/state samples: wrote no trajectory.npz / summary.json '
                f'(config and logs are in {self.out})'
            )
            return {}
        cfg = self.cfg
        # the same function computes `apf-swarm bag metrics` from a recorded bag
        summary = run_summary(
            traj,
            cfg,
            status=status,
            n_samples=len(self.acc.samples),
            dropped=self.acc.dropped,
            respawned=[c.name for c in self.group if c.respawns],
        )
        summary.update(self.run_fields(status))
        if self.prediction is not None:
            summary['prediction'] = self.predicted(traj)
        paths = write_run(self.out, traj, summary, cfg)
        if not self.args.no_plots and len(traj['t']) > 1:
            from ..analysis import plots

            title = f'{cfg.law} law, ROS 2 {self.mode} run'
            paths['trajectories_3d'] = plots.plot_trajectories_3d(
                traj, f'trajectories, {title}', self.out / 'trajectories_3d.png'
            )
            paths['xy_time'] = plots.plot_xy_time(
                traj, f'x and y, {title}', self.out / 'xy_time.png'
            )
            paths['centroid'] = plots.plot_centroid(
                traj, f'formation centre, {title}', self.out / 'centroid.png'
            )
            paths['centroid_error'] = plots.plot_centroid_error(
                {cfg.law: traj},
                f'centroid error, ROS 2 {self.mode} run',
                self.out / 'centroid_error.png',
            )
        print(format_summary(summary))
        pr = summary.get('prediction')
        if pr is not None:

            def judged(f: dict[str, Any]) -> str:
                if f.get('formation_error_rms') is None:
                    return 'no design to judge by'
                return (
                    ('flies' if f['flies'] else 'does not fly') + f': formation error '
                    f'{100 * f["formation_error_rms"]:.2g} %, closest pair '
                    f'{100 * f["closest_pair"]:.3g} %, centroid '
                    f'{f["centroid_error_rms"]:.3g} m'
                )

            print(f'  flight           run {judged(pr["run"])}')
            if 'emulation' in pr:
                print(
                    f"  headless         {judged(pr['emulation'])} (same rate, the run's "
                    f'latencies p50 {1e3 * pr["latency"]["p50"]:.2g} ms, p99 '
                    f'{1e3 * pr["latency"]["p99"]:.2g} ms)'
                )
        m = summary['messages']
        print(
            f'  run              {status}, {self.mode}, ROS_DOMAIN_ID {self.domain_id}, '
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
        figs = [p.name for k, p in paths.items() if p.suffix == '.png']
        print(
            f'wrote {self.out / "trajectory.npz"}, {self.out / "summary.json"}'
            + (f' and {", ".join(figs)}' if figs else '')
        )
        return paths
