#!/usr/bin/env python3
"""Benchmark of the headless simulator against a per-agent Python loop of the same step.

Run from the workspace root (numpy and psutil, no ROS):

    python bench/bench_simulator.py [--quick | --smoke] [--plain]

The baseline (:class:`LoopSimulator`) is the straightforward implementation of one step of
the closed loop: a Python loop over the trackers and over the pairs, with one numpy 3-vector
per tracker -- the gradient of eq. 2 / 44, the proposed sliding-mode controller with the
paper's saturation and its low-pass filter (eq. 22-28, 31, 24, 26), and the plant of eq. 19-21
driven by the same seeded disturbance (:class:`apf_swarm_core.plant.DisturbanceSource`).
Before timing anything the bench checks that the loop reproduces the simulator's trajectory
(to 1e-9 m and m/s over a few hundred steps), so both sides compute the same thing.

Timing: ``time.perf_counter`` around ``BatchSimulator.run(steps, record=...)`` and around the
loop's ``run(steps)``, after a warm-up, alternating the two, several repeats; the table gives
the best and the median time per step, and the floors are judged on the ratio of the bests.
Both sides draw the disturbance in the timed region; the target's
trajectory is evaluated inside the simulator's timed region and precomputed for the loop.

Output: Markdown tables on stdout (``--plain`` for aligned text), progress on stderr. Exit
status 0 when every floor is met, 1 otherwise. ``--smoke`` (seconds: does it still run?)
times tiny cases (no n = 1000, R <= 300) and judges only the loop against the simulator, not
the floors, which a shared machine's load can miss (its tables say "not judged").
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

try:
    import apf_swarm_core  # noqa: F401
    import apf_swarm_nodes  # noqa: F401
except ImportError:  # run without the workspace's environment: its sources (numpy, psutil)
    for pkg in ('apf_swarm_core', 'apf_swarm_nodes'):
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'src' / pkg))

from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.config_files import load_preset
from apf_swarm_core.plant import DisturbanceSource
from apf_swarm_core.simulator import BatchSimulator, initial_positions
from apf_swarm_nodes.capacity.machine import cpu_model

#: floors: the simulator against the naive loop of the same law, single runs
FLOOR_N3 = 5.0  # 3 trackers (the paper's swarm)
FLOOR_N100 = 50.0  # 100 trackers
FLOOR_BATCH = 5e6  # tracker-steps per second, batched runs of 3 trackers


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


class LoopSimulator:
    """The same closed loop as :class:`BatchSimulator`, one tracker and one pair at a time.

    Proposed law with the paper's saturation (eq. 8) only; positions, velocities and filter
    states are lists of numpy 3-vectors; gains are Python floats.
    """

    def __init__(self, cfg: SwarmConfig, steps: int) -> None:
        if cfg.law != 'proposed' or cfg.saturation != 'paper':
            raise ValueError('the loop baseline implements the proposed law with sat of eq. 8')
        self.n = n = cfg.n_trackers
        x0 = initial_positions(cfg)
        self.x = [x0[i].copy() for i in range(n)]
        self.v = [np.zeros(3) for _ in range(n)]
        self.z = [np.zeros(3) for _ in range(n)]
        self.mass = [np.array(row, dtype=float) for row in cfg.mass_matrix_diag()]
        self.k_n, self.k_f, self.a, self.b, self.c = (cfg.k_n, cfg.k_f, cfg.a, cfg.b, cfg.c)
        self.alpha, self.beta, self.gamma = cfg.alpha, cfg.beta, cfg.gamma
        self.u0, self.drag, self.dt = cfg.u0, cfg.drag, cfg.dt
        self.decay = math.exp(-cfg.dt / cfg.lambda_filter)
        self.noise = DisturbanceSource(cfg.seed, n, cfg.f_bar, cfg.noise)
        # the target's path is precomputed (not part of the timed step)
        pos, _ = cfg.target_trajectory_obj.state(np.arange(steps) * cfg.dt)
        self.target = [p.copy() for p in pos]
        self.k = 0

    def step(self) -> None:
        n, x, v, z = self.n, self.x, self.v, self.z
        xt = self.target[self.k]
        dist = self.noise.next()
        # gradient of J (eq. 2 / 44) for every tracker, pair by pair
        grads = []
        for i in range(n):
            g = self.k_n * (x[i] - xt)
            for j in range(n):
                if j != i:
                    d = x[i] - x[j]
                    r2 = d @ d
                    g = g + self.k_f * (self.a - self.b * math.exp(-r2 / self.c)) * d
            grads.append(g)
        # controller (eq. 22-28, 31, 24, 26) and plant (eq. 19-21), tracker by tracker
        dt = self.dt
        for i in range(n):
            g = grads[i]
            if math.sqrt(g @ g) >= self.gamma:
                s = v[i] + self.alpha * g + z[i]
            else:
                s = v[i] + (self.alpha + self.beta / self.gamma) * g
            u = -self.u0 * np.sign(s) + self.drag * v[i]
            z[i] = self.decay * z[i] + (1.0 - self.decay) * self.beta * np.sign(g)
            acc = (u - self.drag * v[i] - dist[i]) / self.mass[i]
            x[i] = x[i] + v[i] * dt + 0.5 * dt * dt * acc
            v[i] = v[i] + acc * dt
        self.k += 1

    def run(self, steps: int, record: bool = False) -> dict[str, np.ndarray]:
        xs, vs = [], []
        for _ in range(steps):
            if record:
                xs.append(np.array(self.x))
                vs.append(np.array(self.v))
            self.step()
        return {'x': np.array(xs), 'v': np.array(vs)} if record else {}


def base_config(n: int, **changes) -> SwarmConfig:
    """The default preset (triangle) with ``n`` trackers; 'uniform_ball' noise."""
    cfg = load_preset('triangle').replace(n_trackers=n, **changes)
    if n > 3:  # keep the swarm's initial spacing comparable to the 3-tracker preset
        cfg = cfg.replace(init_spread=cfg.init_spread * (n / 3) ** (1 / 3))
    return cfg


def verify(n: int, steps: int) -> float:
    """Largest difference between loop and simulator positions/velocities over ``steps``."""
    cfg = base_config(n)
    sim = BatchSimulator([cfg])
    rec = sim.run(steps, record=True)
    loop = LoopSimulator(cfg, steps)
    lrec = loop.run(steps, record=True)
    err = max(np.abs(rec['x'][0] - lrec['x']).max(), np.abs(rec['v'][0] - lrec['v']).max())
    # and the state after the last step
    err = max(
        err, np.abs(sim.x[0] - np.array(loop.x)).max(), np.abs(sim.v[0] - np.array(loop.v)).max()
    )
    return float(err)


def best_and_median(samples: list[float]) -> tuple[float, float]:
    return min(samples), statistics.median(samples)


def single_case(
    n: int, sim_steps: int, loop_steps: int, repeats: int, loop_repeats: int | None = None
) -> dict[str, tuple[float, float]]:
    """Seconds per step (best, median) of a single run of n trackers: the simulator with
    recording off and on, and the loop.

    The three are timed round-robin in short slices (``sim_steps`` / ``loop_steps`` steps),
    ``repeats`` times (the loop ``loop_repeats`` times), so that all see the same machine load.
    """
    cfg = base_config(n)
    loop_repeats = repeats if loop_repeats is None else loop_repeats
    sims = {rec: BatchSimulator([cfg]) for rec in (False, True)}
    for rec, sim in sims.items():
        sim.run(min(sim_steps, 50), record=rec)  # warm-up
    loop = LoopSimulator(cfg, 2 + loop_repeats * loop_steps)
    loop.run(2)
    times: dict[str, list[float]] = {'off': [], 'on': [], 'loop': []}
    for r in range(repeats):
        for rec, sim in sims.items():
            t0 = time.perf_counter()
            sim.run(sim_steps, record=rec)
            times['on' if rec else 'off'].append((time.perf_counter() - t0) / sim_steps)
        if r < loop_repeats:
            t0 = time.perf_counter()
            loop.run(loop_steps)
            times['loop'].append((time.perf_counter() - t0) / loop_steps)
    res = {k: best_and_median(v) for k, v in times.items()}
    log(
        f'  n={n}: simulator best {res["off"][0] * 1e6:.1f} us (record on '
        f'{res["on"][0] * 1e6:.1f} us), loop best {res["loop"][0] * 1e6:.1f} us'
    )
    return res


def batch_case(R: int, steps: int, repeats: int, noise: str) -> tuple[float, float]:
    """Tracker-steps per second (best, median) of R runs of 3 trackers, record off."""
    base = base_config(3, noise=noise)
    t0 = time.perf_counter()
    sim = BatchSimulator([base.replace(seed=s) for s in range(1, R + 1)])
    setup = time.perf_counter() - t0
    sim.run(10, record=False)
    # time at least two refills of the disturbance buffer, so that its cost is amortized
    steps = max(steps, 2 * getattr(sim.noise, '_steps', sim.noise.block))
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sim.run(steps, record=False)
        rates.append(R * 3 * steps / (time.perf_counter() - t0))
    log(
        f'  R={R} noise={noise}: best {max(rates) / 1e6:.2f}, median '
        f'{statistics.median(rates) / 1e6:.2f} M tracker-steps/s (set-up {setup:.1f} s)'
    )
    return max(rates), statistics.median(rates)


def load_average() -> str:
    return ' '.join(f'{v:.2f}' for v in os.getloadavg())


def machine() -> str:
    cpu = cpu_model()
    return (
        f'nproc {os.cpu_count()}, CPU {cpu}, Python {platform.python_version()}, '
        f'numpy {np.__version__}'
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer steps and repeats')
    ap.add_argument(
        '--smoke',
        action='store_true',
        help='tiny cases (seconds); only the loop against the simulator is judged, not floors',
    )
    ap.add_argument('--plain', action='store_true', help='aligned text instead of Markdown')
    args = ap.parse_args(argv)
    q, smoke = args.quick or args.smoke, args.smoke
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    load_start = load_average()

    log('checking that the loop reproduces the simulator ...')
    checks = (
        [(3, 100), (10, 50)]
        if smoke
        else [(3, 300), (10, 100)]
        if q
        else [(3, 500), (10, 300), (100, 20)]
    )
    errors = {}
    for n, steps in checks:
        errors[(n, steps)] = verify(n, steps)
        log(f'  n={n}, {steps} steps: max |loop - simulator| = {errors[(n, steps)]:.2e}')
    ok_verify = all(e <= 1e-9 for e in errors.values())

    log('single runs (simulator and loop timed alternately) ...')
    rows = []  # case, (sim best, median), (loop best, median), floor or None
    single = (
        (3, 2000, 100, 30 if q else 150, None, FLOOR_N3),
        (100, 50, 2, 4 if q else 7, None, FLOOR_N100),
        (1000, 5 if q else 10, 1, 2 if q else 3, 1 if q else 2, None),
    )
    if smoke:
        single = ((3, 2000, 100, 5, None, FLOOR_N3), (100, 10, 1, 2, None, FLOOR_N100))
    for n, sim_steps, loop_steps, reps, loop_reps, floor in single:
        res = single_case(n, sim_steps, loop_steps, reps, loop_reps)
        rows.append((f'n={n}, record off', res['off'], res['loop'], floor))
        rows.append((f'n={n}, record on', res['on'], res['loop'], floor))

    log('batched runs (R runs x 3 trackers, record off) ...')
    batch = []
    Rs = (100, 300) if smoke else (100, 1000, 3000) if q else (100, 300, 1000, 3000, 10000)
    for R in Rs:
        steps = max(20, min(1000, (600_000 if q else 1_500_000) // (R * 3)))
        batch.append((R, 'uniform_ball', batch_case(R, steps, 3 if q else 5, 'uniform_ball')))
    best_R = max(batch, key=lambda b: b[2][0])[0]
    steps = max(20, min(1000, (600_000 if q else 1_500_000) // (best_R * 3)))
    batch.append((best_R, 'none', batch_case(best_R, steps, 3 if q else 5, 'none')))

    md = not args.plain
    out = []
    all_ok = ok_verify
    if md:
        out.append(f'Machine: {machine()}.\n')
        out.append(
            '| case | simulator / step (best, median) | loop / step (best, median) '
            '| ratio of bests | floor | result |'
        )
        out.append('|---|---:|---:|---:|---:|---|')
    else:
        out.append(machine())
        out.append(
            f'{"case":20s}{"simulator/step best, median":>30s}'
            f'{"loop/step best, median":>26s}{"ratio":>8s}{"floor":>7s}  result'
        )
    for case, ts, tl, floor in rows:
        ratio = tl[0] / ts[0]
        res = (
            '(reported)'
            if floor is None
            else f'({"met" if ratio >= floor else "missed"}, not judged)'
            if smoke
            else 'pass'
            if ratio >= floor
            else 'FAIL'
        )
        all_ok &= res != 'FAIL'
        fl = '-' if floor is None else f'{floor:g}x'
        st = f'{fmt_t(ts[0])}, {fmt_t(ts[1])}'
        lt = f'{fmt_t(tl[0])}, {fmt_t(tl[1])}'
        if md:
            out.append(f'| {case} | {st} | {lt} | {ratio:.1f}x | {fl} | {res} |')
        else:
            out.append(f'{case:20s}{st:>30s}{lt:>26s}{ratio:>7.1f}x{fl:>7s}  {res}')
    out.append('')
    if md:
        out.append(
            '| batched, R runs x 3 trackers | noise | time / step (best) '
            '| tracker-steps/s (best, median) | floor | result |'
        )
        out.append('|---|---|---:|---:|---:|---|')
    else:
        out.append(
            f'{"batched R x 3":16s}{"noise":>14s}{"time/step":>12s}'
            f'{"tracker-steps/s best, median":>31s}{"floor":>7s}  result'
        )
    for R, noise, (best, med) in batch:
        if noise != 'uniform_ball':
            res = '(reported)'
        elif best_R == R and smoke:
            res = f'({"met" if best >= FLOOR_BATCH else "missed"}, not judged)'
        elif best_R == R:  # the floor is judged at the best R
            res = 'pass' if best >= FLOOR_BATCH else 'FAIL'
            all_ok &= res == 'pass'
        else:
            res = '(above floor)' if best >= FLOOR_BATCH else '(below floor)'
        tstep = R * 3 / best
        rate = f'{best / 1e6:.2f} M, {med / 1e6:.2f} M'
        if md:
            out.append(f'| R = {R} | {noise} | {fmt_t(tstep)} | {rate} | 5 M | {res} |')
        else:
            out.append(
                f'{"R = " + str(R):16s}{noise:>14s}{fmt_t(tstep):>12s}{rate:>31s}'
                f'{"5 M":>7s}  {res}'
            )
    out.append('')
    checks_txt = ', '.join(f'n={n} over {s} steps: {e:.1e}' for (n, s), e in errors.items())
    out.append(
        f'Loop vs simulator, max |difference| of positions and velocities: {checks_txt} '
        f'({"pass" if ok_verify else "FAIL"}, tolerance 1e-9).'
    )
    wall = time.perf_counter() - t_start
    out.append(
        f'Batched floor judged at the best R ({best_R}). Wall time of the bench: '
        f'{wall:.0f} s, of which this process had the CPU for '
        f'{(time.process_time() - cpu_start) / wall:.0%}; load average (1, 5, 15 min) '
        f'{load_start} at the start, {load_average()} at the end.'
    )
    print('\n'.join(out))
    return 0 if all_ok else 1


def fmt_t(sec: float) -> str:
    if math.isnan(sec):
        return '-'
    if sec < 1e-3:
        return f'{sec * 1e6:.1f} us'
    if sec < 1.0:
        return f'{sec * 1e3:.2f} ms'
    return f'{sec:.2f} s'


if __name__ == '__main__':
    sys.exit(main())
