#!/usr/bin/env python3
"""Benchmark of the headless simulator against a per-agent Python loop of the same step.

The baseline, :class:`LoopSimulator`, steps the closed loop (eq. 2 / 44, 22-28, 31, 24, 26,
19-21, the same seeded disturbance) tracker by tracker and pair by pair; it must reproduce
``BatchSimulator`` to 1e-9 before anything is timed. The two alternate in short slices; floors
on the ratio of the bests, and on batched tracker-steps/s."""

import argparse
import math
import os
import statistics
import sys
from typing import Any

import numpy as np
from _children import log, table, timed
from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.config_files import load_preset
from apf_swarm_core.plant import DisturbanceSource
from apf_swarm_core.simulator import BatchSimulator, initial_positions
from apf_swarm_nodes.capacity.machine import cpu_model

FLOORS = {3: 5.0, 100: 50.0}  # simulator / loop, single runs
FLOOR_BATCH = 5e6  # tracker-steps/s, batched runs of 3 trackers


class LoopSimulator:
    """The closed loop of :class:`BatchSimulator`, one tracker and one pair at a time."""

    def __init__(self, cfg: SwarmConfig, steps: int) -> None:
        self.n = n = cfg.n_trackers
        self.x = [row.copy() for row in initial_positions(cfg)]
        self.v = [np.zeros(3) for _ in range(n)]
        self.z = [np.zeros(3) for _ in range(n)]
        self.mass = [np.array(row, dtype=float) for row in cfg.mass_matrix_diag()]
        self.c = cfg
        self.decay = math.exp(-cfg.dt / cfg.lambda_filter)
        self.noise = DisturbanceSource(cfg.seed, n, cfg.f_bar, cfg.noise)
        self.target = list(cfg.target_trajectory_obj.state(np.arange(steps) * cfg.dt)[0])
        self.k = 0

    def step(self) -> None:
        c, n, x, v, z = self.c, self.n, self.x, self.v, self.z
        xt, dist = self.target[self.k], self.noise.next()
        grads = []
        for i in range(n):
            g = c.k_n * (x[i] - xt)
            for j in range(n):
                if j != i:
                    d = x[i] - x[j]
                    g = g + c.k_f * (c.a - c.b * math.exp(-(d @ d) / c.c)) * d
            grads.append(g)
        for i, g in enumerate(grads):
            if math.sqrt(g @ g) >= c.gamma:
                s = v[i] + c.alpha * g + z[i]
            else:
                s = v[i] + (c.alpha + c.beta / c.gamma) * g
            u = -c.u0 * np.sign(s) + c.drag * v[i]
            z[i] = self.decay * z[i] + (1.0 - self.decay) * c.beta * np.sign(g)
            acc = (u - c.drag * v[i] - dist[i]) / self.mass[i]
            x[i] = x[i] + v[i] * c.dt + 0.5 * c.dt * c.dt * acc
            v[i] = v[i] + acc * c.dt
        self.k += 1

    def run(self, steps: int, record: bool = False) -> dict[str, np.ndarray]:
        xs, vs = [], []
        for _ in range(steps):
            if record:
                xs.append(np.array(self.x))
                vs.append(np.array(self.v))
            self.step()
        return {'x': np.array(xs), 'v': np.array(vs)}


def config(n: int, **changes) -> SwarmConfig:
    cfg = load_preset('triangle').replace(n_trackers=n, **changes)
    return cfg.replace(init_spread=cfg.init_spread * (n / 3) ** (1 / 3)) if n > 3 else cfg


def verify(n: int, steps: int) -> float:
    cfg = config(n)
    sim, loop = BatchSimulator([cfg]), LoopSimulator(cfg, steps)
    rec, lrec = sim.run(steps, record=True), loop.run(steps, record=True)
    return float(max(np.abs(rec['x'][0] - lrec['x']).max(), np.abs(rec['v'][0] - lrec['v']).max(),
                     np.abs(sim.x[0] - np.array(loop.x)).max()))  # fmt: skip


def single(n: int, steps: int, loop_steps: int, reps: int, loop_reps: int) -> dict[str, list]:
    """Seconds per step of the simulator (record off / on) and the loop, round-robin."""
    cfg = config(n)
    sims = {'off': BatchSimulator([cfg]), 'on': BatchSimulator([cfg])}
    for key, sim in sims.items():
        sim.run(min(steps, 50), record=key == 'on')
    loop = LoopSimulator(cfg, 2 + loop_reps * loop_steps)
    loop.run(2)
    times: dict[str, list[float]] = {'off': [], 'on': [], 'loop': []}
    for r in range(reps):
        for key, sim in sims.items():
            times[key].append(timed(sim.run, steps, record=key == 'on') / steps)
        if r < loop_reps:
            times['loop'].append(timed(loop.run, loop_steps) / loop_steps)
    return times


def batch(runs: int, steps: int, reps: int, noise: str) -> list[float]:
    sim = BatchSimulator([config(3, noise=noise).replace(seed=s) for s in range(1, runs + 1)])
    sim.run(10)
    steps = max(steps, 2 * getattr(sim.noise, '_steps', sim.noise.block))  # buffer refills
    return [runs * 3 * steps / timed(sim.run, steps) for _ in range(reps)]


def bm(vals: list[float], f: Any = None) -> str:
    """'best, median' (times: the least; rates, M: the most)."""
    if f is not None:
        return f'{f(min(vals))}, {f(statistics.median(vals))}'
    return f'{max(vals) / 1e6:.2f} M, {statistics.median(vals) / 1e6:.2f} M'


def fmt(sec: float) -> str:
    return f'{sec * 1e6:.1f} µs' if sec < 1e-3 else f'{sec * 1e3:.2f} ms'


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer steps and repeats')
    ap.add_argument('--smoke', action='store_true', help='tiny cases; floors not judged')
    args = ap.parse_args(argv)
    q, smoke, load0 = args.quick or args.smoke, args.smoke, os.getloadavg()[0]
    checks = [(3, 100), (10, 50)] if smoke else [(3, 300), (10, 100)]
    checks += [] if q else [(100, 20)]
    errors = {(n, s): verify(n, s) for n, s in checks}
    ok = agree = all(e <= 1e-9 for e in errors.values())
    cases = [(3, 2000, 100, 5, None), (100, 10, 1, 2, None)] if smoke else [
        (3, 2000, 100, 30 if q else 150, None), (100, 50, 2, 4 if q else 7, None),
        (1000, 5 if q else 10, 1, 2 if q else 3, 1 if q else 2)]  # fmt: skip
    rows = []
    for n, steps, loop_steps, reps, loop_reps in cases:
        log(f'n = {n}')
        t = single(n, steps, loop_steps, reps, reps if loop_reps is None else loop_reps)
        loop = min(t['loop'])
        for key in ('off', 'on'):
            ratio, floor = loop / min(t[key]), FLOORS.get(n)
            met = floor is None or ratio >= floor
            verdict = '(reported)' if floor is None else ('met' if met else 'missed')
            verdict += ', not judged' if smoke and floor else ''
            ok &= met or smoke
            rows.append([f'n={n}, record {key}', bm(t[key], fmt), bm(t['loop'], fmt),
                         f'{ratio:.1f}x', f'{floor:g}x' if floor else '-', verdict])  # fmt: skip
    head = 'case | simulator / step (best, median): | loop / step (best, median): | ratio: '
    print(f'CPU {cpu_model()}, {os.cpu_count()} cores, load {load0:.2f}\n')
    print(table(head + '| floor: | result', rows) + '\n')
    brows, best = [], (0.0, 0)
    for runs in (100, 300) if smoke else (100, 1000, 3000) if q else (100, 300, 1000, 3000, 10000):
        steps = max(20, min(1000, (600_000 if q else 1_500_000) // (runs * 3)))
        rates = batch(runs, steps, 3 if q else 5, 'uniform_ball')
        best = max(best, (max(rates), runs))
        brows.append([f'R = {runs}', 'uniform_ball', fmt(runs * 3 / max(rates)), bm(rates)])
    ok &= smoke or best[0] >= FLOOR_BATCH
    head = 'batched, R x 3 trackers | noise | time / step (best): | '
    print(table(head + 'tracker-steps/s (best, median):', brows))
    print(f'\nBatched floor {FLOOR_BATCH / 1e6:g} M tracker-steps/s at the best R ({best[1]}): '
          f'{"met" if best[0] >= FLOOR_BATCH else "missed"}{", not judged" if smoke else ""}. '
          f'Loop against simulator, max |difference|: '
          + ', '.join(f'n={n} over {s} steps {e:.1e}' for (n, s), e in errors.items())
          + f' ({"pass" if agree else "FAIL"}, tolerance 1e-9).')  # fmt: skip
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
