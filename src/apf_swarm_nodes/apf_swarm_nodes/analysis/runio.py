"""Reading and writing run outputs: ``trajectory.npz``, ``summary.json``, resolved config."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.config_files import to_ros_params
from apf_swarm_core.simulator import TRAJECTORY_KEYS, summarize_run

__all__ = [
    'RUN_ARRAYS',
    'TARGET_SILENT_AGE',
    'fault_report',
    'fmt',
    'format_summary',
    'run_summary',
    'write_run',
]

#: per-sample arrays of a ROS run written to trajectory.npz besides the simulator's: active
#: flags (T, n), target age (T,) [s], each tracker's latest command latency (T, n) [s], the
#: cumulative stale-brake count (T,)
RUN_ARRAYS = ('active', 'target_age', 'command_latency', 'stale_inputs')

#: a target state older than this [s] counts as the target being silent in the fault report
#: (ten periods of the realtime publish rate of 100 Hz; 100 steps of 1 ms in lockstep)
TARGET_SILENT_AGE = 0.1


def _intervals(t: np.ndarray, flag: np.ndarray) -> list[list[float]]:
    """[t_first, t_last] of every run of consecutive samples where ``flag`` holds."""
    edges = np.diff(np.concatenate([[0], np.asarray(flag, dtype=int), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [
        [round(float(t[a]), 6), round(float(t[b]), 6)] for a, b in zip(starts, ends, strict=True)
    ]


def fault_report(
    t: np.ndarray,
    active: np.ndarray | None,
    target_age: np.ndarray | None,
    stale_inputs: np.ndarray | None = None,
) -> tuple[dict[str, Any], list[str]]:
    """The ``faults`` field of summary.json and its warning lines, from the ``active``
    flags (T, n), the ``target_age`` (T,) and the cumulative ``stale_inputs`` count (T,) of
    ``/swarm/state``: when each tracker was inactive (silent past the deadline, zero force,
    out of the formation), when the target was silent (its state older than
    :data:`TARGET_SILENT_AGE`) and when trackers sent the safe brake on inputs that went
    stale (``stale``: the samples at which the count grew; the plant does not count the
    brakes a tracker sends before its first inputs)."""
    faults: dict[str, Any] = {
        'inactive': {},
        'target_silent': [],
        'target_age_max': 0.0,
        'stale': [],
    }
    warnings: list[str] = []
    t = np.asarray(t, dtype=float)
    if active is not None and len(active):
        act = np.asarray(active, dtype=bool)
        for j in range(act.shape[1]):
            spans = _intervals(t, ~act[:, j])
            if spans:
                faults['inactive'][f'uav_{j + 1}'] = spans
                total = sum(b - a for a, b in spans)
                warnings.append(
                    f'uav_{j + 1} was inactive (no command) {len(spans)} time(s), '
                    f'{total:.3g} s in all, first at t = {spans[0][0]:g} s: zero '
                    f'force, out of the formation term of the others'
                )
    if target_age is not None and len(target_age):
        age = np.asarray(target_age, dtype=float)
        faults['target_age_max'] = round(float(age.max()), 6)
        spans = _intervals(t, age > TARGET_SILENT_AGE)
        faults['target_silent'] = spans
        if spans:
            warnings.append(
                f'the target was silent {len(spans)} time(s) (state up to '
                f'{age.max():.3g} s old), first at t = {spans[0][0]:g} s: its '
                f'last state was held, trackers brake past their input_timeout'
            )
    if stale_inputs is not None and len(stale_inputs):
        count = np.asarray(stale_inputs, dtype=float)
        grew = np.diff(count, prepend=0.0) > 0
        spans = _intervals(t, grew)
        faults['stale'] = spans
        if spans:
            warnings.append(
                f'trackers braked on stale inputs {len(spans)} time(s) during the '
                f'run, first at t = {spans[0][0]:g} s ({int(count[-1])} stale '
                f'commands in all)'
            )
    return faults, warnings


def write_run(
    out: Path, traj: Mapping[str, Any], summary: Mapping[str, Any], cfg: SwarmConfig | None = None
) -> dict[str, Path]:
    """Write ``trajectory.npz``, ``summary.json`` and (with ``cfg``) ``config.yaml`` into out.

    ``trajectory.npz`` holds the arrays of the simulator's schema and, from a ROS run, the
    per-sample :data:`RUN_ARRAYS` there are (what the fault report and the latency come
    from, kept so that a run can be examined in time)."""
    out.mkdir(parents=True, exist_ok=True)
    paths = {'trajectory': out / 'trajectory.npz', 'summary': out / 'summary.json'}
    keys = [*TRAJECTORY_KEYS, *(k for k in RUN_ARRAYS if k in traj)]
    arrays: dict[str, Any] = {k: np.asarray(traj[k]) for k in keys}
    np.savez(paths['trajectory'], **arrays)
    paths['summary'].write_text(json.dumps(summary, indent=2) + '\n')
    if cfg is not None:
        paths['config'] = out / 'config.yaml'
        paths['config'].write_text(yaml.safe_dump(to_ros_params(cfg), sort_keys=False))
    return paths


def run_summary(
    traj: Mapping[str, Any],
    cfg: SwarmConfig,
    *,
    status: str = 'completed',
    n_samples: int | None = None,
    dropped: int = 0,
    respawned: Sequence[str] = (),
) -> dict[str, Any]:
    """summary.json (the simulator's schema) of a ROS run from its ``/swarm/state`` trajectory
    (the ``trajectory.npz`` arrays, plus ``active`` (T, n) and ``target_age`` (T,) when the
    samples carry them: they give the ``faults`` field, see :func:`fault_report`).

    The one function behind the bring-up's ``summary.json`` and ``apf-swarm bag metrics``, so
    that a bag recorded by the bring-up gives the live run's summary by construction. Warnings:
    the configuration's, then an incomplete run (``status``), lost samples, respawns.
    """
    from apf_swarm_core.checks import check_config

    from ..advice import CLI_ADVICE

    warnings = list(check_config(cfg, advice=CLI_ADVICE).warnings)
    if status != 'completed':
        n = len(traj['t']) if n_samples is None else n_samples
        warnings.append(f'incomplete run ({status}): {n} samples')
    if dropped:
        warnings.append(f'{dropped} /swarm/state steps were not received')
    if respawned:
        warnings.append(
            f'respawned during the run: {", ".join(respawned)} (a restarted '
            'node starts from its initial state)'
        )
    faults, fault_warnings = fault_report(
        traj['t'], traj.get('active'), traj.get('target_age'), traj.get('stale_inputs')
    )
    summary = summarize_run(
        {k: traj[k] for k in TRAJECTORY_KEYS}, cfg, warnings=warnings + fault_warnings
    )
    summary['faults'] = faults
    return summary


def fmt(v: Any, digits: int = 3) -> str:
    """A value of a summary in a table or a line of text: ``digits`` significant digits,
    yes/no, ``-`` for none, the range of a list of distances (n > 3 designs)."""
    if v is None:
        return '-'
    if isinstance(v, bool):
        return 'yes' if v else 'no'
    if isinstance(v, float):
        return f'{v:.{digits}g}'
    if isinstance(v, (list, tuple)) and v and all(isinstance(e, float) for e in v):
        return f'{len(v)} distances in [{min(v):.{digits}g}, {max(v):.{digits}g}]'
    return str(v)


def format_summary(summary: Mapping[str, Any]) -> str:
    """Human-readable lines of a summary.json document."""
    s = summary
    lines = [
        (
            f'law {s["law"]}, {s["n_trackers"]} trackers, dt {s["dt"]:g} s, '
            f'duration {s["duration"]:g} s, seed {s["seed"]}'
        )
    ]
    ce, fo, ch, po = s['centroid_error'], s['formation'], s['chattering'], s['potential']
    lines.append(
        f'  centroid error   rms_steady {fmt(ce["rms_steady"], 4)} m, max_steady '
        f'{fmt(ce["max_steady"], 4)} m, final {fmt(ce["final"], 4)} m'
    )
    lines.append(
        f'  pair distance    min {fmt(fo["pair_distance_min"], 4)} m, max '
        f'{fmt(fo["pair_distance_max"], 4)} m, mean {fmt(fo["pair_distance_mean"], 4)} m, '
        f'expected {fmt(fo["pair_distance_expected"], 4)} m; closest approach '
        f'{fmt(fo.get("closest_approach"), 4)} m'
    )
    lines.append(f'  formation error  rms_steady {fmt(fo["error_rms_steady"], 4)} m')
    lines.append(
        f'  chattering       hf_velocity_rms {fmt(ch["hf_velocity_rms"], 4)} m/s, '
        f'heading_rate {fmt(ch["heading_rate"], 4)} rad/s'
    )
    lines.append(
        f'  potential J      initial {fmt(po["initial"], 4)}, final {fmt(po["final"], 4)}, '
        f'decreasing {fmt(po["decreasing_fraction"], 4)}'
    )
    lines.append(f'  converged        {s["converged"]} (after {fmt(s["time_to_converge"], 4)} s)')
    for w in s.get('warnings', []):
        lines.append(f'  warning: {w}')
    return '\n'.join(lines)
