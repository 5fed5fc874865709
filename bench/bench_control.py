#!/usr/bin/env python3
"""Benchmark of one tracker's command against a naive numpy loop of the same law.

Run from the workspace root (numpy only, no ROS graph):

    python bench/bench_control.py [--n 3,16,32,64,128] [--calls 300] [--precondition P]
                                  [--json FILE] [--smoke]

What is timed, per swarm size n (the ``realtime`` preset, its formation at the design with
1 cm of noise a call, so every call sees new positions):

* ``offer + command``: :meth:`TrackerAgent.offer_swarm` of one ``/swarm/odom`` of n trackers
  and :meth:`TrackerAgent.command` -- what a tracker node does per state, less the message
  conversion and the publication;
* ``command``: :meth:`TrackerAgent.command` alone (the number the floors of issue 22 name);
* ``naive``: a plain per-tracker numpy implementation of the same command for one tracker
  (the gradient row of eq. 2 / 44 as a loop-free sum, the tracker's own 3x3 Hessian block,
  the centroid apart, the proposed manifold in its linear layer, the boundary-layer
  switching and the filter of eq. 26; no input checks, no delay compensation), written the
  way a first implementation would be: the baseline measured in the same run.

Each number is the mean and the p99 over ``--calls`` calls after 20 of warm-up, alternating
the three in slices of 10 calls so that a busy moment hits all of them. ``--precondition``
overrides the preset's direction (any value the configuration accepts). Output: a Markdown
table on stdout with the CPU model, ``--json FILE`` writes
``{"rows": [{"n": .., "mean_us": .., "p99_us": .., ...}, ...]}`` (``mean_us`` and ``p99_us``:
the command). ``--smoke``: n = 3 and 16, 30 calls. Exit status 0, or 1 when the block
direction's command grows from 32 to 128 trackers by more than 6x (the floor), when both
are measured.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

try:
    import apf_swarm_core  # noqa: F401
except ImportError:  # run from the workspace root without PYTHONPATH
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'src' / 'apf_swarm_core'))

from apf_swarm_core.agents import TrackerAgent
from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.config_files import apply_overrides, load_preset
from apf_swarm_core.formation import design_formation

#: the command may grow at most this much from 32 to 128 trackers (linear is 4x)
FLOOR_GROWTH = 6.0
WARMUP = 20
SLICE = 10


def cpu_model() -> str:
    """The CPU model as /proc/cpuinfo names it."""
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return 'unknown CPU'


class Naive:
    """The same command for one tracker, written plainly (the baseline)."""

    def __init__(self, cfg: SwarmConfig) -> None:
        p = cfg.potential_params()
        self.kn, self.kf, self.a, self.b, self.c = (
            float(p[k]) for k in ('k_n', 'k_f', 'a', 'b', 'c')
        )
        self.K = cfg.alpha + cfg.beta / cfg.gamma
        self.alpha, self.u0, self.phi, self.drag = cfg.alpha, cfg.u0, cfg.phi, cfg.drag
        self.decay = float(np.exp(-cfg.control_period / cfg.lambda_filter))
        self.beta, self.mu, self.trust = cfg.beta, cfg.newton_mu, cfg.newton_trust
        self.z = np.zeros(3)

    def command(
        self, i: int, x: np.ndarray, v: np.ndarray, tx: np.ndarray, tv: np.ndarray
    ) -> np.ndarray:
        d = x[i] - x
        r2 = np.sum(d * d, axis=1)
        e = np.exp(-r2 / self.c)
        e[i] = 0.0
        w = self.a - self.b * e
        w[i] = 0.0
        g = self.kn * (x[i] - tx) + self.kf * (w[:, None] * d).sum(axis=0)
        h = self.kn * np.eye(3) + self.kf * (
            w.sum() * np.eye(3)
            + (2 * self.b / self.c)
            * (e[:, None, None] * d[:, :, None] * d[:, None, :]).sum(axis=0)
        )
        gbar = self.kn * (x.mean(axis=0) - tx)
        lam, vec = np.linalg.eigh(h)
        rel = g - gbar
        floor = max(self.mu, float(np.linalg.norm(rel)) / self.trust) if self.trust else self.mu
        delta = gbar / self.kn + vec @ ((vec.T @ rel) / np.maximum(np.abs(lam), floor))
        s = (v[i] - tv) + self.alpha * delta + self.K * delta + self.z
        u = -self.u0 * np.clip(s / self.phi, -1.0, 1.0) + self.drag * v[i]
        self.z = self.decay * self.z + (1 - self.decay) * self.beta * delta
        return u


def measure(cfg: SwarmConfig, calls: int) -> dict[str, Any]:
    n = cfg.n_trackers
    rng = np.random.default_rng(0)
    x0 = design_formation(cfg).relative_positions + np.array([0.0, 0.0, 5.0])
    v = rng.normal(scale=0.1, size=(n, 3))
    tx, tv = np.array([0.0, 0.0, 5.0]), np.array([1.5, 0.0, 0.0])
    ids, active = list(range(1, n + 1)), [True] * n
    agent, naive = TrackerAgent(cfg, 1), Naive(cfg)
    times: dict[str, list[float]] = {'offer_command': [], 'command': [], 'naive': []}
    seq = 0
    total = WARMUP + calls
    while len(times['naive']) < total:
        for _ in range(SLICE):  # agent: offer then command, each timed
            x = x0 + rng.normal(scale=0.01, size=x0.shape)
            seq += 1
            t0 = time.perf_counter()
            agent.offer_swarm(-1, ids, x, v, active, tx, tv, 0.0, 0.0, seq=seq)
            t1 = time.perf_counter()
            agent.command(-1)
            t2 = time.perf_counter()
            times['offer_command'].append(t2 - t0)
            times['command'].append(t2 - t1)
        for _ in range(SLICE):
            x = x0 + rng.normal(scale=0.01, size=x0.shape)
            t0 = time.perf_counter()
            naive.command(0, x, v, tx, tv)
            times['naive'].append(time.perf_counter() - t0)
    row: dict[str, Any] = {'n': n, 'precondition': cfg.precondition}
    for key, vals in times.items():
        arr = 1e6 * np.asarray(vals[WARMUP:total])
        row[f'{key}_mean_us'] = round(float(arr.mean()), 1)
        row[f'{key}_p99_us'] = round(float(np.quantile(arr, 0.99)), 1)
    row['mean_us'], row['p99_us'] = row['command_mean_us'], row['command_p99_us']
    row['ratio_to_naive'] = round(row['command_mean_us'] / row['naive_mean_us'], 2)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--n', default='3,16,32,64,128', help='swarm sizes, comma-separated')
    ap.add_argument('--calls', type=int, default=300, help='timed calls per size')
    ap.add_argument('--precondition', default=None, help="the direction (default: the preset's)")
    ap.add_argument('--json', type=Path, default=None, metavar='FILE')
    ap.add_argument('--smoke', action='store_true', help='n = 3 and 16, 30 calls (seconds)')
    args = ap.parse_args(argv)
    sizes = [3, 16] if args.smoke else [int(s) for s in args.n.split(',')]
    calls = 30 if args.smoke else args.calls
    base = load_preset('realtime')
    if args.precondition:
        base = apply_overrides(base, {'precondition': args.precondition})
    rows = []
    for n in sizes:
        cfg = base.replace(n_trackers=n, control_rate=50.0, latency=0.01)
        rows.append(measure(cfg, calls))
        print(f'bench_control: n = {n} done', file=sys.stderr, flush=True)
    print(f'\nCPU: {cpu_model()}; direction: {base.precondition}; {calls} calls per size\n')
    print(
        '| n | offer + command mean / p99 [µs] | command mean / p99 [µs] '
        '| naive mean / p99 [µs] | command / naive |'
    )
    print('|---:|---:|---:|---:|---:|')
    for r in rows:
        print(
            f'| {r["n"]} | {r["offer_command_mean_us"]:.0f} / {r["offer_command_p99_us"]:.0f} | '
            f'{r["command_mean_us"]:.0f} / {r["command_p99_us"]:.0f} | '
            f'{r["naive_mean_us"]:.0f} / {r["naive_p99_us"]:.0f} | {r["ratio_to_naive"]:.2f} |'
        )
    if args.json:
        args.json.write_text(json.dumps({'cpu': cpu_model(), 'rows': rows}, indent=2) + '\n')
    by_n = {r['n']: r for r in rows}
    if base.precondition == 'block' and 32 in by_n and 128 in by_n:
        growth = by_n[128]['mean_us'] / by_n[32]['mean_us']
        print(f'\ncommand 128 / 32 trackers: {growth:.2f}x (floor {FLOOR_GROWTH:g}x)')
        return 0 if growth <= FLOOR_GROWTH else 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
