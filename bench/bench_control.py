#!/usr/bin/env python3
"""Benchmark of one tracker's command against a naive numpy command of the same law.

Run from the workspace root (numpy and psutil, no ROS graph):

    python bench/bench_control.py [--n 3,16,32,64,128] [--calls 200] [--precondition P]
                                  [--json FILE] [--smoke]

What is timed, per swarm size n, with the ``realtime`` preset (its precondition and
compensation, sampled at 50 Hz with 10 ms of latency) and the states of its designed
formation around the target with 1 cm of noise a call (every call sees new positions):

* ``command``: :meth:`TrackerAgent.command` of tracker 1 after
  :meth:`TrackerAgent.offer_swarm` of every tracker's state and the target's (what a tracker
  node computes per state, less the message conversion and the publication); the offer is
  timed apart (``offer + command``);
* ``naive``, the baseline measured in the same run: :class:`Naive`, the same law's
  gradient-only command for one tracker written plainly in numpy -- the gradient row of eq. 2 /
  44, the proposed manifold with the paper's saturation (eq. 28 / 31), the switching force of
  eq. 24 (with the preset's boundary layer) and the filter of eq. 26; no preconditioning, no
  delay compensation, no input checks. Before timing, it is checked against
  ``TrackerAgent.command`` with ``precondition=none`` and ``compensation=none`` (the same
  law): the forces must agree to 1e-9, else the bench fails.

Each number is the mean, the median and the p99 over ``--calls`` calls after 20 of warm-up
(the median resists the preemptions of a shared machine better than the mean), the command
and the baseline alternating in slices of 10 calls so that a busy moment hits both.
``--precondition`` overrides the preset's direction (any value the configuration accepts).
Output: the CPU model, then a Markdown table on stdout; ``--json FILE`` writes
``{"rows": [{"n": .., "mean_us": .., "p99_us": .., ...}, ...]}`` (``mean_us`` and ``p99_us``:
the command; the other fields: the offer, the baseline, the ratios). ``--smoke``: n = 3 and 16,
20 calls. Exit status 0; 1 when the baseline disagrees with the command, or when the block
direction's command grows from 32 to 128 trackers by more than 6x (the floor; when both are
measured); 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

try:
    import apf_swarm_core  # noqa: F401
    import apf_swarm_nodes  # noqa: F401
except ImportError:  # run without the workspace's environment: its sources (numpy, psutil)
    for pkg in ('apf_swarm_core', 'apf_swarm_nodes'):
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'src' / pkg))

from apf_swarm_core.agents import TrackerAgent
from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.config_files import apply_overrides, load_preset
from apf_swarm_core.formation import design_formation
from apf_swarm_nodes.capacity.machine import cpu_model

#: the command may grow at most this much from 32 to 128 trackers (linear is 4x)
FLOOR_GROWTH = 6.0
WARMUP = 20
SLICE = 10
TARGET_X = np.array([0.0, 0.0, 5.0])
TARGET_V = np.array([1.5, 0.0, 0.0])


class Naive:
    """The law's gradient-only command for one tracker, written plainly (the baseline)."""

    def __init__(self, cfg: SwarmConfig, dt: float) -> None:
        p = cfg.potential_params()
        self.kn, self.kf, self.a, self.b, self.c = (
            float(p[k]) for k in ('k_n', 'k_f', 'a', 'b', 'c')
        )
        self.alpha, self.beta, self.gamma = cfg.alpha, cfg.beta, cfg.gamma
        self.u0, self.phi, self.drag, self.ff = cfg.u0, cfg.phi, cfg.drag, cfg.feedforward
        self.layer = cfg.switching == 'layer'
        self.decay = math.exp(-dt / cfg.lambda_filter)
        self.z = np.zeros(3)

    def command(
        self, i: int, x: np.ndarray, v: np.ndarray, tx: np.ndarray, tv: np.ndarray
    ) -> np.ndarray:
        d = x[i] - x  # x_i - x_j (row i is zero)
        w = self.a - self.b * np.exp(-(d * d).sum(axis=1) / self.c)
        g = self.kn * (x[i] - tx) + self.kf * (w[:, None] * d).sum(axis=0)  # eq. 2 / 44, row i
        vs = v[i] - self.ff * tv
        if np.linalg.norm(g) >= self.gamma:  # eq. 28, outside the boundary layer
            s = vs + self.alpha * g + self.z
        else:  # eq. 31, inside
            s = vs + (self.alpha + self.beta / self.gamma) * g
        sw = np.clip(s / self.phi, -1.0, 1.0) if self.layer else np.sign(s)
        u = -self.u0 * sw + self.drag * v[i]  # eq. 24
        self.z = self.decay * self.z + (1.0 - self.decay) * self.beta * np.sign(g)  # eq. 26
        return u


def formation(cfg: SwarmConfig) -> np.ndarray:
    """The designed formation of ``cfg.n_trackers`` around the target [m]."""
    return design_formation(cfg).relative_positions + TARGET_X


def check(cfg: SwarmConfig, calls: int = 20) -> float:
    """Largest difference between the baseline's force and ``TrackerAgent.command`` of the
    same law (``precondition=none``, ``compensation=none``), on states at the formation and
    far from it: both sides of the boundary layer must be seen."""
    plain = cfg.replace(precondition='none', compensation='none')
    n = cfg.n_trackers
    agent = TrackerAgent(plain, 1)
    naive = Naive(plain, agent.controller.dt)
    rng = np.random.default_rng(1)
    x0 = formation(plain)
    ids, active = list(range(1, n + 1)), [True] * n
    worst, sides = 0.0, set()
    for k in range(calls):
        x = x0 + rng.normal(scale=0.5, size=x0.shape) * (k % 2)
        v = rng.normal(scale=0.5, size=(n, 3))
        if not agent.offer_swarm(-1, ids, x, v, active, TARGET_X, TARGET_V, 0.0, 0.0, seq=k):
            raise RuntimeError(f'offer_swarm refused the state: {agent.last_rejection}')
        out = agent.command(-1)
        sides.add(bool(out.saturated[0]))
        got = naive.command(0, x, v, TARGET_X, TARGET_V)
        ref = out.force[0]
        worst = max(worst, float(np.max(np.abs(ref - got)) / max(1.0, np.max(np.abs(ref)))))
    if len(sides) < 2:
        raise RuntimeError(f'the check saw one side of the boundary layer only ({sides})')
    return worst


def measure(cfg: SwarmConfig, calls: int) -> dict[str, Any]:
    """Mean and p99 [µs] of the command, the offer and the baseline for one swarm size."""
    n = cfg.n_trackers
    rng = np.random.default_rng(0)
    x0 = formation(cfg)
    v = rng.normal(scale=0.1, size=(n, 3))
    ids, active = list(range(1, n + 1)), [True] * n
    agent = TrackerAgent(cfg, 1)
    naive = Naive(cfg, agent.controller.dt)
    times: dict[str, list[float]] = {'offer_command': [], 'command': [], 'naive': []}
    seq = 0
    total = WARMUP + calls
    while len(times['naive']) < total:
        for _ in range(SLICE):
            x = x0 + rng.normal(scale=0.01, size=x0.shape)
            seq += 1
            t0 = time.perf_counter()
            agent.offer_swarm(-1, ids, x, v, active, TARGET_X, TARGET_V, 0.0, 0.0, seq=seq)
            t1 = time.perf_counter()
            agent.command(-1)
            t2 = time.perf_counter()
            times['offer_command'].append(t2 - t0)
            times['command'].append(t2 - t1)
        for _ in range(SLICE):
            x = x0 + rng.normal(scale=0.01, size=x0.shape)
            t0 = time.perf_counter()
            naive.command(0, x, v, TARGET_X, TARGET_V)
            times['naive'].append(time.perf_counter() - t0)
    if agent.rejected:
        raise RuntimeError(f'offer_swarm refused a state: {agent.last_rejection}')
    row: dict[str, Any] = {'n': n, 'precondition': cfg.precondition, 'calls': calls}
    for key, vals in times.items():
        arr = 1e6 * np.asarray(vals[WARMUP:total])
        row[f'{key}_mean_us'] = round(float(arr.mean()), 1)
        row[f'{key}_p50_us'] = round(float(np.median(arr)), 1)
        row[f'{key}_p99_us'] = round(float(np.quantile(arr, 0.99)), 1)
    row['mean_us'], row['p99_us'] = row['command_mean_us'], row['command_p99_us']
    row['ratio_to_naive'] = round(row['command_mean_us'] / row['naive_mean_us'], 2)
    row['ratio_to_naive_p50'] = round(row['command_p50_us'] / row['naive_p50_us'], 2)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--n', default='3,16,32,64,128', help='swarm sizes, comma-separated')
    ap.add_argument('--calls', type=int, default=200, help='timed calls per size')
    ap.add_argument(
        '--precondition',
        default=None,
        help="the direction, any value the configuration accepts (default: the preset's)",
    )
    ap.add_argument('--json', type=Path, default=None, metavar='FILE', help='rows as JSON')
    ap.add_argument('--smoke', action='store_true', help='n = 3 and 16, 20 calls (seconds)')
    args = ap.parse_args(argv)
    try:
        sizes = [3, 16] if args.smoke else [int(s) for s in args.n.split(',')]
    except ValueError:
        ap.error(f'--n {args.n!r}: comma-separated integers expected')
    calls = 20 if args.smoke else args.calls
    if calls < 1 or min(sizes) < 1:
        ap.error('--calls and every --n must be at least 1')
    base = load_preset('realtime')
    if args.precondition:
        try:
            base = apply_overrides(base, {'precondition': args.precondition})
        except (ValueError, TypeError) as exc:  # ConfigError is a ValueError
            ap.error(f'--precondition {args.precondition!r}: {exc}')
    base = base.replace(control_rate=50.0, latency=0.01)
    load = ' '.join(f'{x:.2f}' for x in os.getloadavg())
    print(
        f'CPU: {cpu_model()}, {os.cpu_count()} cores; Python {platform.python_version()}, '
        f'numpy {np.__version__}; load average {load} at the start\n'
        f'preset realtime: precondition {base.precondition}, compensation '
        f'{base.compensation}, control_rate {base.control_rate:g} Hz, latency '
        f'{base.latency * 1e3:g} ms; {calls} calls per size after {WARMUP} of warm-up',
        flush=True,
    )
    rows, worst = [], 0.0
    for n in sizes:
        cfg = base.replace(n_trackers=n)
        err = check(cfg)
        worst = max(worst, err)
        if err > 1e-9:
            print(
                f'bench_control: the baseline differs from TrackerAgent.command '
                f'(precondition=none) at n = {n} by {err:.3g} (relative): broken',
                file=sys.stderr,
            )
            return 1
        rows.append(measure(cfg, calls))
        print(f'bench_control: n = {n} done', file=sys.stderr, flush=True)
    print(
        '\n| n | command mean / p50 / p99 [µs] | naive mean / p50 / p99 [µs] '
        '| command / naive (means, medians) | offer + command mean / p99 [µs] |'
    )
    print('|---:|---:|---:|---:|---:|')

    def us(r: dict[str, Any], key: str, stats: tuple[str, ...]) -> str:
        return ' / '.join(f'{r[f"{key}_{q}_us"]:.0f}' for q in stats)

    for r in rows:
        print(
            f'| {r["n"]} | {us(r, "command", ("mean", "p50", "p99"))} '
            f'| {us(r, "naive", ("mean", "p50", "p99"))} '
            f'| {r["ratio_to_naive"]:.2f}, {r["ratio_to_naive_p50"]:.2f} '
            f'| {us(r, "offer_command", ("mean", "p99"))} |'
        )
    print(
        f'\nBaseline against TrackerAgent.command with precondition=none, compensation=none: '
        f'largest relative difference of the force {worst:.1e} (limit 1e-9).'
    )
    if args.json:
        args.json.write_text(json.dumps({'rows': rows}, indent=2) + '\n')
    by_n = {r['n']: r for r in rows}
    if base.precondition == 'block' and 32 in by_n and 128 in by_n:
        growth = by_n[128]['mean_us'] / by_n[32]['mean_us']
        print(f'command 128 / 32 trackers: {growth:.2f}x (floor {FLOOR_GROWTH:g}x)')
        return 0 if growth <= FLOOR_GROWTH else 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
