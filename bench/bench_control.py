#!/usr/bin/env python3
"""Benchmark of one tracker's command against a naive numpy command of the same law.

``realtime`` preset (50 Hz, 10 ms), states at the formation with 1 cm of noise a call: tracker
1's :meth:`TrackerAgent.command` after ``offer_swarm`` (timed apart) against :class:`Naive`,
the gradient-only command in plain numpy, first checked equal to it with ``precondition=none,
compensation=none`` (1e-9). Mean, median, p99 after 20 calls of warm-up, alternating in slices
of 10. Exit 1 when the baseline disagrees, or the block direction's command grows over 6x from
32 to 128 trackers."""

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _children import log, table
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
        p = {k: float(v) for k, v in cfg.potential_params().items()}
        self.kn, self.kf, self.a, self.b, self.c = (p[k] for k in ('k_n', 'k_f', 'a', 'b', 'c'))
        self.alpha, self.beta, self.gamma = cfg.alpha, cfg.beta, cfg.gamma
        self.u0, self.phi, self.drag, self.ff = cfg.u0, cfg.phi, cfg.drag, cfg.feedforward
        self.layer = cfg.switching == 'layer'
        self.decay = math.exp(-dt / cfg.lambda_filter)
        self.z = np.zeros(3)

    def command(self, i: int, x: np.ndarray, v: np.ndarray, tx: Any, tv: Any) -> np.ndarray:
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


def check(cfg: SwarmConfig, calls: int = 20) -> float:
    """Largest relative difference of the baseline's force from ``TrackerAgent.command`` of
    the same law, at the formation and far from it (both sides of the boundary layer)."""
    plain, n = cfg.replace(precondition='none', compensation='none'), cfg.n_trackers
    agent = TrackerAgent(plain, 1)
    naive, rng = Naive(plain, agent.controller.dt), np.random.default_rng(1)
    x0 = design_formation(plain).relative_positions + TARGET_X
    ids, active = list(range(1, n + 1)), [True] * n
    worst, sides = 0.0, set()
    for k in range(calls):
        x = x0 + rng.normal(scale=0.5, size=x0.shape) * (k % 2)
        v = rng.normal(scale=0.5, size=(n, 3))
        if not agent.offer_swarm(-1, ids, x, v, active, TARGET_X, TARGET_V, 0.0, 0.0, seq=k):
            raise RuntimeError(f'offer_swarm refused the state: {agent.last_rejection}')
        out = agent.command(-1)
        sides.add(bool(out.saturated[0]))
        got, ref = naive.command(0, x, v, TARGET_X, TARGET_V), out.force[0]
        worst = max(worst, float(np.max(np.abs(ref - got)) / max(1.0, np.max(np.abs(ref)))))
    if len(sides) < 2:
        raise RuntimeError(f'the check saw one side of the boundary layer only ({sides})')
    return worst


def measure(cfg: SwarmConfig, calls: int) -> dict[str, Any]:
    """Mean and p99 [µs] of the command, the offer and the baseline for one swarm size."""
    n, rng = cfg.n_trackers, np.random.default_rng(0)
    x0 = design_formation(cfg).relative_positions + TARGET_X
    v = rng.normal(scale=0.1, size=(n, 3))
    ids, active = list(range(1, n + 1)), [True] * n
    agent = TrackerAgent(cfg, 1)
    naive, seq, total = Naive(cfg, agent.controller.dt), 0, WARMUP + calls
    times: dict[str, list[float]] = {'offer_command': [], 'command': [], 'naive': []}
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
        stats = {'mean': arr.mean(), 'p50': np.median(arr), 'p99': np.quantile(arr, 0.99)}
        row.update({f'{key}_{q}_us': round(float(v), 1) for q, v in stats.items()})
    row['mean_us'], row['p99_us'] = row['command_mean_us'], row['command_p99_us']
    row['ratio_to_naive'] = round(row['command_mean_us'] / row['naive_mean_us'], 2)
    row['ratio_to_naive_p50'] = round(row['command_p50_us'] / row['naive_p50_us'], 2)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--n', default='3,16,32,64,128', help='swarm sizes, comma-separated')
    ap.add_argument('--calls', type=int, default=200, help='timed calls per size')
    ap.add_argument('--precondition', default=None, help="default: the preset's")
    ap.add_argument('--json', type=Path, metavar='FILE', help='{"rows": [{"n", "mean_us", ...}]}')
    ap.add_argument('--smoke', action='store_true', help='n = 3 and 16, 20 calls (seconds)')
    args = ap.parse_args(argv)
    try:
        sizes = [3, 16] if args.smoke else [int(s) for s in args.n.split(',')]
        base = load_preset('realtime').replace(control_rate=50.0, latency=0.01)
        if args.precondition:
            base = apply_overrides(base, {'precondition': args.precondition})
    except (ValueError, TypeError) as exc:  # ConfigError is a ValueError
        ap.error(str(exc))
    calls = 20 if args.smoke else args.calls
    if calls < 1 or min(sizes) < 1:
        ap.error('--calls and every --n must be at least 1')
    print(f'CPU: {cpu_model()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}; '
          f'realtime: precondition {base.precondition}, compensation {base.compensation}; '
          f'{calls} calls after {WARMUP} of warm-up', flush=True)  # fmt: skip
    rows, worst = [], 0.0
    for n in sizes:
        cfg = base.replace(n_trackers=n)
        worst = max(worst, check(cfg))
        if worst > 1e-9:
            log(f'the baseline differs by {worst:.3g} at n = {n}')
            return 1
        rows.append(measure(cfg, calls))

    def us(r: dict[str, Any], key: str, stats: tuple[str, ...]) -> str:
        return ' / '.join(f'{r[f"{key}_{q}_us"]:.0f}' for q in stats)

    head = 'n: | command mean / p50 / p99 [µs]: | naive mean / p50 / p99 [µs]: | command / naive '
    print('\n' + table(head + '(means, medians): | offer + command mean / p99 [µs]:', [
        [r['n'], us(r, 'command', ('mean', 'p50', 'p99')), us(r, 'naive', ('mean', 'p50', 'p99')),
         f'{r["ratio_to_naive"]:.2f}, {r["ratio_to_naive_p50"]:.2f}',
         us(r, 'offer_command', ('mean', 'p99'))] for r in rows]))  # fmt: skip
    print(f'\nBaseline against the command (precondition=none, compensation=none): largest '
          f'relative difference of the force {worst:.1e} (limit 1e-9).')  # fmt: skip
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
