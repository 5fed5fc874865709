#!/usr/bin/env python3
"""The swarm split across simulated hosts: network namespaces joined by veth pairs.

    sudo python scripts/multihost.py --hosts 3 --n-trackers 6 --out DIR
    sudo python scripts/multihost.py --hosts 3 --open --discovery server --mode realtime --out DIR

Makes a private "switch" namespace with a bridge and ``--hosts`` host namespaces, each with its
own address on a private /24 that exists only inside them (``10.231.X.h``, X from this
process's id, so two labs never share one), plugged into the bridge by a veth pair, with a
multicast route. Host 1 runs the plant, the target and the bring-up (which observes
``/swarm/state`` and writes the usual outputs into ``--out``); the trackers (``K`` per
process with ``--trackers-per-process``) go round-robin to hosts 2..H, each process forked by
the bring-up's zygote straight into its host's namespace (``setns``, as ``ip netns exec``
does, without starting Python anew; docs/PERFORMANCE.md). By default the run
is secure (``swarm_up.py --secure``, :mod:`apf_swarm_nodes.dds.secure`): TCP with TLS only, a
certificate per host from the run's own authority, discovery through the bring-up's server.
``--open``: DDS uses UDP only (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``: ``/dev/shm`` is shared
between namespaces) and discovers either by multicast on the subnet
(``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``) or through the Fast DDS discovery server shipped
in the wheels, run on host 1 (``--discovery server``, ``ROS_DISCOVERY_SERVER``); anyone on
the network can then see and steer the swarm. No address outside these namespaces and
loopback is used. At the end it prints the CPU each host's processes used and writes
``multihost.json``; the namespaces are removed whatever happens (``--keep`` keeps them).

Needs root and ``ip`` (iproute2). Exit status: the bring-up's, or 2 for bad input / a
machine that cannot make namespaces.
"""

from __future__ import annotations

import argparse
import contextlib
import glob
import json
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SERVER_PORT = 11811


def say(msg: str) -> None:
    print(f'multihost: {msg}', file=sys.stderr, flush=True)


def ip(*args: str) -> None:
    """``ip ARGS``; raises RuntimeError with ip's message when it fails."""
    p = subprocess.run(['ip', *args], capture_output=True, text=True, timeout=30)
    if p.returncode != 0:
        raise RuntimeError(f'ip {" ".join(args)}: {p.stderr.strip() or p.returncode}')


def unavailable() -> str | None:
    """Why this machine cannot run the lab (None when it can)."""
    if os.geteuid() != 0:
        return 'needs root (network namespaces)'
    if shutil.which('ip') is None:
        return 'needs `ip` from iproute2 (apt-get install iproute2)'
    probe = f'apfprobe{os.getpid()}'
    try:
        ip('netns', 'add', probe)
    except RuntimeError as exc:
        return f'cannot create a network namespace: {exc}'
    with contextlib.suppress(RuntimeError):
        ip('netns', 'del', probe)
    return None


class Lab:
    """A bridge namespace and ``hosts`` host namespaces on a private /24; removed on exit."""

    def __init__(self, hosts: int, tag: str | None = None) -> None:
        self.tag = tag or f'{os.getpid() % 100000}'
        self.switch = f'apf{self.tag}sw'
        self.hosts = [f'apf{self.tag}h{h}' for h in range(1, hosts + 1)]
        self.net = f'10.231.{os.getpid() % 250}'
        self.addr = {ns: f'{self.net}.{h}' for h, ns in enumerate(self.hosts, start=1)}
        self.made: list[str] = []

    def __enter__(self) -> Lab:
        try:
            ip('netns', 'add', self.switch)
            self.made.append(self.switch)
            ip('-n', self.switch, 'link', 'add', 'br0', 'type', 'bridge')
            ip('-n', self.switch, 'link', 'set', 'br0', 'up')
            for h, ns in enumerate(self.hosts, start=1):
                ip('netns', 'add', ns)
                self.made.append(ns)
                ip(
                    'link',
                    'add',
                    'eth0',
                    'netns',
                    ns,
                    'type',
                    'veth',
                    'peer',
                    'name',
                    f'p{h}',
                    'netns',
                    self.switch,
                )
                ip('-n', self.switch, 'link', 'set', f'p{h}', 'master', 'br0')
                ip('-n', self.switch, 'link', 'set', f'p{h}', 'up')
                ip('-n', ns, 'addr', 'add', f'{self.addr[ns]}/24', 'dev', 'eth0')
                ip('-n', ns, 'link', 'set', 'eth0', 'up')
                ip('-n', ns, 'link', 'set', 'lo', 'up')
                ip('-n', ns, 'route', 'add', '224.0.0.0/4', 'dev', 'eth0')
        except BaseException:
            self.remove()
            raise
        return self

    def __exit__(self, *exc: Any) -> None:
        self.remove()

    def remove(self) -> None:
        for ns in reversed(self.made):
            try:
                ip('netns', 'del', ns)
            except RuntimeError as exc:
                say(f'could not remove namespace {ns}: {exc}')
        self.made.clear()

    def inode(self, ns: str) -> int:
        return os.stat(f'/run/netns/{ns}').st_ino


def tracker_process_names(n: int, per_process: int) -> list[str]:
    """The bring-up's log names of the tracker processes (``bringup.node_commands``)."""
    if per_process <= 1:
        return [f'tracker_{i}' for i in range(1, n + 1)]
    return [f'trackers_{a}-{min(n, a + per_process - 1)}' for a in range(1, n + 1, per_process)]


def fastdds_library_path() -> str:
    """LD_LIBRARY_PATH for the wheels' fast-discovery-server binary."""
    venv = Path(sys.prefix)
    dirs = [
        str(venv / 'lib'),
        *sorted(glob.glob(str(Path(sysconfig.get_paths()['purelib']) / 'ros_fastrtps.libs'))),
    ]
    old = os.environ.get('LD_LIBRARY_PATH')
    return os.pathsep.join(dirs + ([old] if old else []))


class HostCpu:
    """CPU used by the processes of each host namespace (those naming ``needle``)."""

    def __init__(self, lab: Lab, needle: str) -> None:
        self.by_inode = {lab.inode(ns): ns for ns in lab.hosts}
        self.needle = needle
        self.last: dict[int, float] = {}
        self.used = dict.fromkeys(lab.hosts, 0.0)
        #: the most node processes running at once (a restarted one replaces its first)
        self.procs = dict.fromkeys(lab.hosts, 0)

    def sample(self) -> None:
        from apf_swarm_nodes.capacity.machine import process_cpu_seconds

        now = dict.fromkeys(self.procs, 0)
        for entry in os.listdir('/proc'):
            if not entry.isdigit():
                continue
            pid = int(entry)
            try:
                with open(f'/proc/{pid}/cmdline', 'rb') as f:
                    if self.needle.encode() not in f.read():
                        continue
                ns = self.by_inode.get(os.stat(f'/proc/{pid}/ns/net').st_ino)
            except OSError:
                continue
            used = process_cpu_seconds(pid)
            if ns is None or used is None:
                continue
            self.used[ns] += used - self.last.get(pid, used)
            self.last[pid] = used
            now[ns] += 1
        for ns, count in now.items():
            self.procs[ns] = max(self.procs[ns], count)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--hosts', type=int, default=3, help='simulated hosts (>= 2)')
    p.add_argument('--n-trackers', type=int, default=3)
    p.add_argument(
        '--trackers-per-process',
        type=int,
        default=0,
        help='trackers hosted in one process (default 0: what the bring-up picks on one '
        'machine, apf-swarm probe)',
    )
    p.add_argument(
        '--discovery',
        choices=('multicast', 'server'),
        default='multicast',
        help='--open only: UDP multicast on the subnet, or the Fast DDS discovery server '
        '(a secure run has its own, on TCP with TLS, in the bring-up)',
    )
    p.add_argument(
        '--open',
        action='store_true',
        help='UDP, open to anyone on the network (the default is --secure: TCP with TLS, '
        "only the run's hosts admitted; docs/RELIABILITY.md)",
    )
    p.add_argument('--mode', choices=('lockstep', 'realtime'), default='lockstep')
    p.add_argument('--preset', default=None, help='default: triangle (lockstep), realtime')
    p.add_argument('--duration', type=float, default=5.0)
    p.add_argument(
        '--rate',
        type=float,
        default=None,
        help="realtime: the control rate (plant publications, trackers' watchdog) "
        '[Hz]; default: what this machine carries (apf-swarm probe)',
    )
    p.add_argument('--domain-id', type=int, default=None)
    p.add_argument('--out', type=Path, required=True)
    p.add_argument('--keep', action='store_true', help='keep the namespaces (debugging)')
    args = p.parse_args(argv)
    if not args.open and args.discovery == 'server':
        p.error('--discovery server: only with --open (a secure run has its own server)')
    if args.hosts < 2:
        p.error('--hosts: at least 2 (one for the plant and target, one for trackers)')
    why = unavailable()
    if why is not None:
        print(
            f'multihost.py: error: this machine cannot run simulated hosts: {why}', file=sys.stderr
        )
        return 2
    try:
        from apf_swarm_nodes.bringup import stop_process
    except ImportError as exc:
        print(
            f'multihost.py: error: {exc}; run `make setup` and `source scripts/activate.sh` first',
            file=sys.stderr,
        )
        return 2
    preset = args.preset or ('realtime' if args.mode == 'realtime' else 'triangle')
    out = args.out.resolve()
    with Lab(args.hosts) as lab:
        h1 = lab.hosts[0]
        env = dict(os.environ, PYTHONUNBUFFERED='1')
        if args.open:
            env['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'
        server = None
        if args.discovery == 'server':
            exe = shutil.which('fast-discovery-server') or str(
                Path(sys.prefix) / 'bin' / 'fast-discovery-server'
            )
            server = subprocess.Popen(
                [
                    'ip',
                    'netns',
                    'exec',
                    h1,
                    'env',
                    f'LD_LIBRARY_PATH={fastdds_library_path()}',
                    exe,
                    '-i',
                    '0',
                    '-l',
                    lab.addr[h1],
                    '-p',
                    str(SERVER_PORT),
                ],
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
            line = server.stdout.readline().decode(errors='replace')
            while line and 'Server is running' not in line:
                line = server.stdout.readline().decode(errors='replace')
            if not line:
                print('multihost.py: error: the discovery server did not start', file=sys.stderr)
                return 2
            env['ROS_DISCOVERY_SERVER'] = f'{lab.addr[h1]}:{SERVER_PORT}'
            # plain clients only learn the endpoints they match; the bring-up waits on the
            # whole graph, so every participant is a super client (sees everything)
            env['ROS_SUPER_CLIENT'] = 'TRUE'
        if args.trackers_per_process <= 0:
            from apf_swarm_nodes.capacity import probe

            args.trackers_per_process = probe.trackers_per_process(
                probe.load(), args.n_trackers, args.rate
            )
        names = tracker_process_names(args.n_trackers, args.trackers_per_process)
        tracker_hosts = lab.hosts[1:]
        placement = {name: tracker_hosts[k % len(tracker_hosts)] for k, name in enumerate(names)}
        cmd = [
            'ip',
            'netns',
            'exec',
            h1,
            sys.executable,
            str(ROOT / 'scripts' / 'swarm_up.py'),
            '--preset',
            preset,
            '--mode',
            args.mode,
            '--n-trackers',
            str(args.n_trackers),
            '--trackers-per-process',
            str(args.trackers_per_process),
            '--duration',
            str(args.duration),
            '--discovery-range',
            'SUBNET',
            '--out',
            str(out),
            '--no-plots',
            '--allow-overload',
        ]
        if not args.open:
            cmd += ['--secure', '--secure-address', lab.addr[h1]]
        if args.domain_id is not None:
            cmd += ['--domain-id', str(args.domain_id)]
        if args.rate is not None:
            cmd += ['--set', f'control_rate={float(args.rate)!r}']
        for name, ns in placement.items():
            cmd += ['--node-netns', f'{name}={ns}']
        say(
            f'{args.hosts} hosts on {lab.net}.0/24 '
            f'({", ".join(f"{ns}={a}" for ns, a in lab.addr.items())}), '
            + (
                'secure (TCP with TLS), discovery server in the bring-up; '
                if not args.open
                else f'open (UDP), discovery {args.discovery}; '
            )
            + 'host 1: plant, target, bring-up; trackers: '
            + ', '.join(f'{n}@{ns}' for n, ns in placement.items())
        )
        cpu = HostCpu(lab, str(out / 'config.yaml'))
        bring = subprocess.Popen(
            cmd, env=env, stdin=subprocess.DEVNULL, cwd=ROOT, start_new_session=True
        )
        t0 = time.monotonic()
        try:
            while bring.poll() is None:
                cpu.sample()
                with contextlib.suppress(subprocess.TimeoutExpired):
                    bring.wait(1.0)
        except KeyboardInterrupt:
            os.killpg(bring.pid, signal.SIGINT)
            bring.wait(60)
        finally:
            wall = time.monotonic() - t0
            if server is not None:
                stop_process(server, ((signal.SIGINT, 10.0), (signal.SIGKILL, 5.0)))
            if args.keep:
                lab.made.clear()
                say(f'kept the namespaces {lab.switch} {" ".join(lab.hosts)}')
        rc = bring.returncode
        hosts = []
        for h, ns in enumerate(lab.hosts, start=1):
            role = (
                'plant, target, bring-up'
                if h == 1
                else ', '.join(n for n, where in placement.items() if where == ns) or '-'
            )
            hosts.append(
                {
                    'host': h,
                    'netns': ns,
                    'address': lab.addr[ns],
                    'runs': role,
                    'processes': cpu.procs[ns],
                    'cpu_pct': round(100.0 * cpu.used[ns] / wall, 1),
                }
            )
        result = {
            'hosts': hosts,
            'secure': not args.open,
            'discovery': 'server' if not args.open else args.discovery,
            'mode': args.mode,
            'n_trackers': args.n_trackers,
            'trackers_per_process': args.trackers_per_process,
            'wall_s': round(wall, 2),
            'bringup_exit': rc,
        }
        out.mkdir(parents=True, exist_ok=True)
        (out / 'multihost.json').write_text(json.dumps(result, indent=2) + '\n')
        print('\n| host | address | runs | node processes | CPU [% of a core] |')
        print('|---:|---|---|---:|---:|')
        for r in hosts:
            print(
                f'| {r["host"]} | {r["address"]} | {r["runs"]} | {r["processes"]} | '
                f'{r["cpu_pct"]:.1f} |'
            )
        print(f'\nwall time {wall:.1f} s, discovery {result["discovery"]}, bring-up exit {rc}')
        return rc


if __name__ == '__main__':
    sys.exit(main())
