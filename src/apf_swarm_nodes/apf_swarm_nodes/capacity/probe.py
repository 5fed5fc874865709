"""Capacity probe (``apf-swarm probe``): this machine's control-loop latency and cost per
message, measured once (:mod:`.measure`) and cached, and what follows from them
(:func:`derive`: the latency ``check`` and ``design`` assume, how many trackers fit at each
rate, the default rate; :func:`process_limit`: how many tracker processes the bring-up
starts). Machines of one kind differ 3-4x in speed, so these come from the machine in use.

The cache is ``$APF_SWARM_CACHE/probe.json``, else ``$XDG_CACHE_HOME/apf_swarm/probe.json``
(``~/.cache``), measured again for another machine (CPU model, cores, host name) or with
``--refresh``. ``python -m apf_swarm_nodes.capacity.probe --measure`` measures in a process
of its own (JSON on stdout); ``--echo`` is the measurement's echo process.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from .machine import identity

__all__ = [
    'CPU_BUDGET',
    'MEMORY_BUDGET',
    'PROCESSES_PER_CORE',
    'RATES',
    'add_arguments',
    'cache_path',
    'derive',
    'ensure',
    'ensure_or_warn',
    'load',
    'process_limit',
    'run',
    'trackers_per_process',
]

#: the share of the machine's cores the swarm's messages and commands may take
CPU_BUDGET = 0.5
#: the share of the memory available at start that the node processes may take
MEMORY_BUDGET = 0.5
#: what a cached probe must hold; one without all of them is measured again
FIELDS = ('machine', 'rtt', 'cpu_per_message', 'state_cost', 'state_cost_p99', 'process_rss')
#: the tracker processes the bring-up aims at per core when it hosts the trackers
#: several to a process (:func:`trackers_per_process`)
PROCESSES_PER_CORE = 4
#: the rates the default is chosen from [Hz], highest first
RATES = (100.0, 50.0, 20.0)


def cache_path() -> Path:
    """Where the probe is kept."""
    base = os.environ.get('APF_SWARM_CACHE')
    if base:
        return Path(base) / 'probe.json'
    xdg = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(xdg) / 'apf_swarm' / 'probe.json'


def load() -> dict[str, Any] | None:
    """The cached probe of this machine, or None (none, unreadable, another machine)."""
    try:
        probe = json.loads(cache_path().read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(probe, dict) or any(k not in probe for k in FIELDS):
        return None
    return probe if probe['machine'] == identity() else None


def ensure(refresh: bool = False, say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The cached probe, measured (and cached) first when missing or ``refresh``."""
    probe = None if refresh else load()
    if probe is None:
        from ..dds.domains import pick_domain_id

        if say is not None:
            say(f'measuring this machine (capacity probe, about 6 s; cached in {cache_path()})')
        env = {
            **os.environ,
            'ROS_DOMAIN_ID': str(pick_domain_id()),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        }
        env.pop('ROS_STATIC_PEERS', None)
        from ..lifetime import dying_with_parent

        # it ends with this process, however this one ends (a killed `apf-swarm probe`)
        done = subprocess.run(
            dying_with_parent(
                [sys.executable, '-m', 'apf_swarm_nodes.capacity.probe', '--measure'], 'INT'
            ),
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        if done.returncode != 0:
            raise RuntimeError(
                f'the capacity probe failed (exit {done.returncode}): {done.stderr.strip()[-800:]}'
            )
        probe = json.loads(done.stdout)
        path = cache_path()
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(probe, indent=2) + '\n')
    return probe


def ensure_or_warn(say: Callable[[str], None] | None, instead: str) -> dict[str, Any] | None:
    """:func:`ensure`, or None when the probe cannot run, said as ``warning: WHY; instead``."""
    try:
        return ensure(say=say)
    except (RuntimeError, OSError, ValueError, subprocess.TimeoutExpired) as exc:
        if say is not None:
            say(f'warning: {exc}; {instead}')
        return None


def _state_cost_at(probe: dict[str, Any], n: int, key: str = 'state_cost') -> float:
    """The probe's mean cost of a tracker's state (``key = 'state_cost_p99'``: its p99) for n
    trackers [s]: interpolated between the measured sizes, linear in n beyond them (the
    block direction's cost grows with the tracker's own gradient)."""
    table = probe.get(key) or probe['state_cost']
    sizes = np.array(sorted(int(k) for k in table))
    costs = np.array([table[str(k)] for k in sizes])
    if n > sizes[-1]:
        return float(costs[-1] * n / sizes[-1])
    return float(np.interp(n, sizes, costs))


def trackers_per_process(probe: dict[str, Any] | None, n: int, rate: float | None = None) -> int:
    """How many trackers the bring-up hosts in one process by default: about
    :data:`PROCESSES_PER_CORE` tracker processes per core (one process per tracker for
    small swarms), and no more in one process than half a control period of commands at the
    p99 cost (``rate`` [Hz], default the lowest of :data:`RATES`). A process of K trackers
    receives each swarm state once for all K, so per tracker it costs ``msg / K`` less.
    Without a probe: the machine's cores alone."""
    cores = int(probe['machine']['cores']) if probe else (os.cpu_count() or 1)
    k = max(1, -(-n // (PROCESSES_PER_CORE * cores)))
    if probe:
        period = 1.0 / (rate or RATES[-1])
        each = _state_cost_at(probe, n, 'state_cost_p99') + 2.0 * float(probe['cpu_per_message'])
        k = min(k, max(1, int(0.5 * period / each)))
    return k


def derive(
    probe: dict[str, Any], n: int, rate: float | None = None, per_process: int = 1
) -> dict[str, Any]:
    """What the probe implies for n trackers hosted ``per_process`` to a process:
    ``capacity`` (trackers that fit in CPU_BUDGET of the cores, per rate of RATES and the
    given one), ``rate`` (the given one, or the default: the highest of RATES that fits n,
    else the lowest), the swarm's CPU ``utilization`` at that rate (mean costs), and the
    ``latency`` [s] check and design assume: the idle round trip's p90 plus the longer of
    the process's commands at their p99 and the swarm's burst (every tracker wakes on the
    same state, so the last command waits until the cores have done the work of all n),
    stretched by ``1 / (1 - utilization)`` (capped at 0.9) for the queueing of a busy
    machine."""
    cores = int(probe['machine']['cores'])
    msg = float(probe['cpu_per_message'])
    cmd = _state_cost_at(probe, n)
    k = max(1, int(per_process))
    # the swarm's state in (once per process), its command out, the plant's in, a command
    per_tracker = msg / k + 2.0 * msg + cmd
    rates = RATES if rate is None or rate in RATES else (*RATES, float(rate))
    capacity = {f'{r:g}': int(CPU_BUDGET * cores / (r * per_tracker)) for r in rates}
    if rate is None:
        rate = next((r for r in RATES if capacity[f'{r:g}'] >= n), RATES[-1])
    use = min(0.9, n * rate * per_tracker / cores)
    tail = k * _state_cost_at(probe, n, 'state_cost_p99')
    burst = n * per_tracker / cores
    latency = (float(probe['rtt']['p90']) + max(tail, burst)) / (1.0 - use)
    return {
        'latency': round(latency, 6),
        'capacity': capacity,
        'rate': float(rate),
        'utilization': round(use, 3),
        'per_tracker_cpu': round(per_tracker, 7),
        'trackers_per_process': k,
    }


def largest_swarm(probe: dict[str, Any], rate: float | None = None) -> int:
    """The most trackers this machine carries at ``rate`` [Hz] (default the lowest of
    :data:`RATES`, where the most fit): the largest n whose :func:`derive` capacity, hosted as
    the bring-up hosts them by default (:func:`trackers_per_process`), is at least n; 0 if not
    even one fits. The capacity falls as n grows (a command costs more, the state is
    larger), so the search is a bisection."""
    rate = float(rate or RATES[-1])

    def fits(n: int) -> bool:
        k = trackers_per_process(probe, n, rate)
        return bool(derive(probe, n, rate, k)['capacity'][f'{rate:g}'] >= n)

    if not fits(1):
        return 0
    lo, hi = 1, 1 << 16
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if fits(mid) else (lo, mid - 1)
    return lo


def process_limit(probe: dict[str, Any], available: int | None = None) -> dict[str, int]:
    """The most tracker processes the bring-up starts without ``--allow-overload``.

    ``cpu``: one-tracker processes that fit in :data:`CPU_BUDGET` of the cores at the lowest
    of :data:`RATES` (:func:`derive`; a process of K trackers costs less); ``memory``: node
    processes of the probe's resident set that fit in :data:`MEMORY_BUDGET` of ``available``
    bytes (default: the memory available now); ``processes``: the smaller, at least 1."""
    if available is None:
        available = int(psutil.virtual_memory().available)
    cpu = derive(probe, 1, RATES[-1])['capacity'][f'{RATES[-1]:g}']
    memory = int(MEMORY_BUDGET * available / max(1, int(probe['process_rss'])))
    return {'processes': max(1, min(cpu, memory)), 'cpu': cpu, 'memory': memory}


def add_arguments(p: Any) -> None:
    """The options of ``apf-swarm probe``."""
    p.add_argument('--refresh', action='store_true', help='measure again')
    p.add_argument(
        '--n-trackers',
        type=int,
        default=16,
        metavar='N',
        help='the swarm size to derive the latency and default rate for',
    )
    p.add_argument('--json', action='store_true')


def run(args: Any) -> int:
    """``apf-swarm probe``: measure (or read the cache) and print what follows."""
    probe = ensure(args.refresh, say=lambda s: print(f'apf-swarm probe: {s}', file=sys.stderr))
    k = trackers_per_process(probe, args.n_trackers)
    d = derive(probe, args.n_trackers, per_process=k)
    if args.json:
        print(
            json.dumps(
                {
                    'probe': probe,
                    'derived': d,
                    'n_trackers': args.n_trackers,
                    'process_limit': process_limit(probe),
                },
                indent=2,
            )
        )
        return 0
    m, r = probe['machine'], probe['rtt']
    print(f'{m["cpu"]}, {m["cores"]} cores ({probe["measured_at"]}, {cache_path()})')
    print(
        f'  round trip at {probe["rate"]:g} Hz: p50 {1e3 * r["p50"]:.2f} ms, p90 '
        f'{1e3 * r["p90"]:.2f} ms, p99 {1e3 * r["p99"]:.2f} ms; CPU per message '
        f'{1e6 * probe["cpu_per_message"]:.0f} us'
    )
    tails = probe.get('state_cost_p99', {})
    print(
        "  a tracker's state (offer + command, mean / p99): "
        + ', '.join(
            f'{1e6 * v:.0f} / {1e6 * tails.get(n, v):.0f} us for {n}'
            for n, v in probe['state_cost'].items()
        )
    )
    lim = process_limit(probe)
    print(
        f'  memory per node process {probe["process_rss"] / 2**20:.0f} MiB; the bring-up '
        f'starts up to {lim["processes"]} tracker processes (CPU at {RATES[-1]:g} Hz: '
        f'{lim["cpu"]}, memory: {lim["memory"]})'
    )
    print(
        f'  {args.n_trackers} trackers, {k} to a process: latency {1e3 * d["latency"]:.2f} '
        f'ms, default rate {d["rate"]:g} Hz; trackers that fit in {CPU_BUDGET:.0%} of the '
        'cores: ' + ', '.join(f'{v} at {k} Hz' for k, v in d['capacity'].items())
    )
    return 0


if __name__ == '__main__':
    # ``--measure``: the probe's own process (JSON on stdout); ``--echo``: its echo
    from .measure import echo, measure

    if sys.argv[1:] == ['--measure']:
        print(json.dumps(measure()))
        sys.exit(0)
    sys.exit(echo() if sys.argv[1:] == ['--echo'] else 2)
