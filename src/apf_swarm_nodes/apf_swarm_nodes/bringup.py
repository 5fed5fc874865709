"""Bring-up of the ROS 2 swarm without ``launch``: ``scripts/swarm_up.py`` / ``apf-swarm up``.

What a run does, in order:

1. resolve the configuration (preset or ``--config`` file, ``--set``, ``--n-trackers``,
   ``--seed``, ``--duration``) and write it to ``DIR/config.yaml`` -- the one parameter file
   every node reads;
2. isolate the run: ``ROS_DOMAIN_ID`` (``--domain-id`` or a random free-looking domain in
   1..101, never the inherited one) and ``ROS_AUTOMATIC_DISCOVERY_RANGE`` (``LOCALHOST``
   unless ``--discovery-range`` says otherwise), set in this process's environment before
   ``rclpy.init`` and inherited by every child;
3. start one OS process per node (``target``, ``plant``, ``tracker`` x n), each in its own
   process group, output to ``DIR/logs/<name>.log``;
4. wait, bounded by ``--ready-timeout``, until the ROS graph shows every node and every
   expected publisher / subscriber (:func:`expected_graph`), polling the graph API from a
   ``spin_once`` loop; then publish ``/swarm/start`` once (reliable, transient local);
5. accumulate ``/swarm/state`` (:class:`StateAccumulator`) with a progress line about once a
   second, supervising the children (respawn or stop), until the run ends: lockstep when the
   sample of step ``steps - 1`` arrived, realtime when the plant's final state arrived (its
   clock starts once every tracker commands from its inputs, node parameter ``arm_timeout``);
6. stop every child (:class:`ProcessGroup`: SIGINT to its group, then SIGTERM, then SIGKILL,
   each bounded) and check by PID that nothing is left;
7. write ``trajectory.npz`` and ``summary.json`` (the schema of ``apf-swarm simulate`` plus the
   run fields listed in :func:`run_fields`) and the figures.

With ``--record`` the recorder (``recorder`` executable, bag ``DIR/bag/``) starts first, in a
group of its own; step 4 also waits until its ``/recorder/status`` shows every swarm topic
recorded with every publisher matched; it is stopped last (SIGINT, it drains and closes the
bag) and its received / written / dropped counts go into ``summary.json`` (``recording``).
A recorder that dies stops the run (a restarted one could not continue the bag).

Exit codes: 0 success, 2 bad input or graph not ready in time, 3 a child died (without
``--respawn``, or after ``--max-respawns``), 4 no ``/swarm/state`` for ``--stall-timeout``,
5 a lockstep run completed but ``/swarm/state`` samples were lost (``trajectory.npz`` has gaps),
130 interrupted (SIGINT or SIGTERM).

This module imports rclpy only inside :func:`run`, so the ``apf-swarm`` parser stays light, and
the process supervision (:class:`Child`, :class:`ProcessGroup`), the graph expectations
(:func:`expected_graph`, :func:`graph_missing`) and the accumulation
(:class:`StateAccumulator`) are usable and testable without ROS.
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import fcntl
import math
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import psutil
from apf_swarm_core.config import (
    DEFAULT_LATENCY,
    REALTIME_RATE,
    SwarmConfig,
    preset_names,
    resolve,
    to_ros_params,
)
from apf_swarm_core.errors import ApfSwarmError

from .argtypes import domain_id, nonneg_int, positive_float, positive_int
from .errors import CliError
from .machine import group_members

__all__ = [
    'EXIT_BAD_INPUT',
    'EXIT_CHILD_DIED',
    'EXIT_INTERRUPTED',
    'EXIT_OK',
    'EXIT_STALLED',
    'Child',
    'ProcessGroup',
    'StateAccumulator',
    'TopicExpectation',
    'add_arguments',
    'build_parser',
    'domain_looks_busy',
    'expected_graph',
    'graph_missing',
    'main',
    'node_commands',
    'pick_domain_id',
    'resolve_config',
    'run',
    'stop_process',
]

PACKAGE = 'apf_swarm_nodes'
EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_CHILD_DIED = 3
EXIT_STALLED = 4
EXIT_LOST_SAMPLES = 5
EXIT_INTERRUPTED = 130

#: escalation of :meth:`ProcessGroup.stop_all`: (signal, seconds to wait after it)
STOP_SEQUENCE = ((signal.SIGINT, 5.0), (signal.SIGTERM, 3.0), (signal.SIGKILL, 2.0))

DISCOVERY_RANGES = ('LOCALHOST', 'SUBNET', 'SYSTEM_DEFAULT', 'OFF')


# --------------------------------------------------------------------------------------------
# process supervision (no ROS)
# --------------------------------------------------------------------------------------------


def _describe_rc(rc: int) -> str:
    if rc < 0:
        try:
            return f'killed by {signal.Signals(-rc).name}'
        except ValueError:
            return f'killed by signal {-rc}'
    return f'exit code {rc}'


def stop_process(
    popen: subprocess.Popen,
    sequence: Sequence[tuple[int, float]] = ((signal.SIGINT, 30.0), (signal.SIGKILL, 5.0)),
) -> int | None:
    """Stop one process started with ``start_new_session=True``: each signal of ``sequence``
    to its process group, then wait at most that many seconds, until it has exited. Returns
    its exit code (None if it outlived every signal). :meth:`ProcessGroup.stop_all` does the
    same for a whole graph, and also waits for every member of each group."""
    for sig, wait_s in sequence:
        if popen.poll() is not None:
            break
        with contextlib.suppress(ProcessLookupError):
            os.killpg(popen.pid, sig)
        try:
            popen.wait(wait_s)
        except subprocess.TimeoutExpired:
            continue
    return popen.poll()


def _group_alive(pgid: int) -> bool:
    """True while process group ``pgid`` has a member that is not a zombie."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # zombies answer kill(0) too (and PID 1 of a container may never reap them)
    return bool(group_members(pgid))


def tail_lines(path: Path, n: int = 10, max_bytes: int = 16384) -> list[str]:
    """The last ``n`` lines of a text file (empty list if unreadable)."""
    try:
        with open(path, 'rb') as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - max_bytes))
            data = f.read()
    except OSError:
        return []
    lines = data.decode('utf-8', errors='replace').splitlines()
    return lines[-n:]


@dataclass
class Child:
    """One supervised OS process: its own process group, output appended to ``log_path``."""

    name: str
    argv: list[str]
    log_path: Path
    env: Mapping[str, str] | None = None
    cwd: Path | None = None
    popen: subprocess.Popen[bytes] | None = None
    starts: int = 0
    stopping: bool = False
    pids: list[int] = field(default_factory=list)

    def start(self) -> None:
        """Start (or restart) the process; the log is appended to, with a header on restarts."""
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, 'ab') as log:
            if self.starts:
                log.write(
                    f'\n===== {self.name}: restart {self.starts} at '
                    f'{time.strftime("%H:%M:%S")} =====\n'.encode()
                )
                log.flush()
            self.popen = subprocess.Popen(
                self.argv,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                env=dict(self.env) if self.env is not None else None,
                cwd=self.cwd,
                start_new_session=True,
                close_fds=True,
            )
        self.starts += 1
        self.stopping = False
        self.pids.append(self.popen.pid)

    @property
    def pid(self) -> int | None:
        return self.popen.pid if self.popen is not None else None

    @property
    def respawns(self) -> int:
        return max(0, self.starts - 1)

    def poll(self) -> int | None:
        """The exit code once the process ended (reaped), else None (also when never started)."""
        return self.popen.poll() if self.popen is not None else None

    @property
    def running(self) -> bool:
        return self.popen is not None and self.popen.poll() is None

    def signal_group(self, sig: int) -> None:
        """Send ``sig`` to the child's process group (no error if it is gone); a stopped
        (SIGSTOP, Ctrl-Z) process is continued so that it can handle SIGINT / SIGTERM."""
        if self.popen is None:
            return
        try:
            os.killpg(self.popen.pid, sig)
            if sig not in (signal.SIGKILL, signal.SIGCONT):
                os.killpg(self.popen.pid, signal.SIGCONT)
        except ProcessLookupError:
            pass

    def tail(self, n: int = 10) -> list[str]:
        return tail_lines(self.log_path, n)

    def death_report(self, rc: int, n: int = 10) -> str:
        """Multi-line report of an unexpected exit: name, pid, exit code, last log lines."""
        lines = self.tail(n)
        head = (
            f'{self.name} (pid {self.pid}) died unexpectedly: {_describe_rc(rc)}; '
            f'last {len(lines)} lines of {self.log_path}:'
        )
        return '\n'.join([head] + [f'    | {ln}' for ln in lines])


class ProcessGroup:
    """A set of :class:`Child` processes started, polled and stopped together."""

    def __init__(self, stop_sequence: Sequence[tuple[int, float]] = STOP_SEQUENCE) -> None:
        self.children: list[Child] = []
        self.stop_sequence = tuple(stop_sequence)

    def add(self, child: Child) -> Child:
        if any(c.name == child.name for c in self.children):
            raise ValueError(f'duplicate child name {child.name!r}')
        self.children.append(child)
        return child

    def __iter__(self):
        return iter(self.children)

    def start_all(self) -> None:
        for c in self.children:
            c.start()

    def poll(self) -> list[tuple[Child, int]]:
        """Children that exited since they were (re)started and were not asked to stop."""
        return [(c, rc) for c in self.children if not c.stopping and (rc := c.poll()) is not None]

    def stop_all(
        self, *, hurry: Callable[[], int] | None = None, poll_interval: float = 0.02
    ) -> dict[str, str]:
        """Stop every running child: SIGINT to each group, wait, SIGTERM, wait, SIGKILL.

        A child counts as stopped when its process has exited (and is reaped) and its process
        group has no member left. Each stage waits at most its time in :attr:`stop_sequence`
        and ends early once every child is stopped, or when ``hurry()`` (a counter, e.g. of
        signals received) grows: each further Ctrl-C moves on to the next stage at once.
        Returns ``{name: how}``, ``how`` one of
        ``exited`` (had already ended), ``SIGINT``, ``SIGTERM``, ``SIGKILL`` (the signal after
        which it stopped) or ``not stopped`` (should never happen; see :meth:`leftovers`).
        """

        def stopped(c: Child) -> bool:
            return c.poll() is not None and not _group_alive(c.popen.pid)

        how: dict[str, str] = {}
        pending = []
        for c in self.children:
            if c.popen is None:
                continue
            c.stopping = True
            if stopped(c):
                how[c.name] = 'exited'
            else:
                pending.append(c)
        for sig, wait_s in self.stop_sequence:
            if not pending:
                break
            for c in pending:
                c.signal_group(sig)
            deadline = time.monotonic() + wait_s
            hurried = hurry() if hurry else 0
            while pending:
                still = []
                for c in pending:
                    if stopped(c):
                        how[c.name] = signal.Signals(sig).name
                    else:
                        still.append(c)
                pending = still
                if not pending or time.monotonic() >= deadline:
                    break
                if hurry is not None and hurry() > hurried:
                    break
                time.sleep(poll_interval)
        for c in pending:
            how[c.name] = 'not stopped'
        return how

    def leftovers(self) -> list[tuple[str, int]]:
        """(name, pid) of every live process in a process group this group ever started
        (each start is a new session: process group id = the child's pid); empty when clean."""
        return [
            (c.name, member)
            for c in self.children
            for pid in c.pids
            for member in group_members(pid)
        ]


# --------------------------------------------------------------------------------------------
# the graph: what must be there before the start
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicExpectation:
    """A topic and the publisher / subscriber counts the graph must show.

    ``or_subscribers_of``: subscribers of that other topic count too (a tracker reads its
    inputs either from the per-UAV odometry topics or from the aggregate ``/swarm/odom``).
    ``optional``: only checked when the topic has a subscriber (``/swarm/odom`` when no
    tracker reads it).
    """

    topic: str
    publishers: int
    subscribers: int
    or_subscribers_of: str | None = None
    optional: bool = False


SWARM_ODOM = '/swarm/odom'


def expected_graph(
    n: int, mode: str, readers: int | None = None
) -> tuple[list[str], list[TopicExpectation]]:
    """Fully qualified node names and topic endpoint counts of a swarm of ``n`` trackers.

    Every tracker reads every tracker's odometry and the target's, either as ``/uav_<j>/odom``
    and ``/target/odom`` (``inputs:=odom``) or as the one aggregate ``/swarm/odom`` message per
    step (``inputs:=aggregate``); the counts accept either. ``readers``: how many subscribe
    to each (default n; a realtime process of several trackers reads ``/swarm/odom`` once,
    see :func:`input_readers`). ``/swarm/start`` and this node's
    ``/swarm/state`` subscription are checked on its own endpoints (matched counts), see
    :meth:`Bringup.missing`.
    """
    nodes = ['/target/target', '/plant'] + [f'/uav_{i}/tracker' for i in range(1, n + 1)]
    topics = []
    readers = n if readers is None else readers
    for i in range(1, n + 1):
        topics.append(TopicExpectation(f'/uav_{i}/odom', 1, readers, or_subscribers_of=SWARM_ODOM))
        topics.append(TopicExpectation(f'/uav_{i}/force_cmd', 1, 1))
    topics.append(TopicExpectation('/target/odom', 1, readers + 1, or_subscribers_of=SWARM_ODOM))
    topics.append(TopicExpectation(SWARM_ODOM, 1, 0, optional=True))
    if mode == 'lockstep':
        topics.append(TopicExpectation('/clock', 1, 0))
        topics.append(TopicExpectation('/target/request', 1, 1))
    topics.append(TopicExpectation('/swarm/state', 1, 1))
    return nodes, topics


def input_readers(n: int, mode: str, per_process: int, node_params: Sequence[str] = ()) -> int:
    """How many subscribers read the trackers' inputs: one per tracker, except in realtime
    with the aggregate inputs, where a process of several trackers subscribes to
    ``/swarm/odom`` once and hands each message to its other nodes (the ``trackers``
    executable): one per process."""
    inputs = next(
        (p.split(':=', 1)[1] for p in reversed(node_params) if p.startswith('inputs:=')),
        'aggregate',
    )
    if mode == 'realtime' and per_process > 1 and inputs == 'aggregate':
        return -(-n // per_process)
    return n


def graph_missing(
    present_nodes: Iterable[str],
    counts: Mapping[str, tuple[int, int]],
    nodes: Sequence[str],
    topics: Sequence[TopicExpectation],
) -> list[str]:
    """What is not there yet, in words (empty when the graph is complete).

    ``counts`` maps a topic to its (publishers, subscribers) as the graph shows them.
    """
    present = set(present_nodes)
    out = [f'node {name}' for name in nodes if name not in present]
    for t in topics:
        pubs, subs = counts.get(t.topic, (0, 0))
        if t.optional and subs == 0:
            continue
        extra = counts.get(t.or_subscribers_of, (0, 0))[1] if t.or_subscribers_of else 0
        if pubs < t.publishers or subs + extra < t.subscribers:
            sub_text = f'{subs}' + (
                f' + {extra} on {t.or_subscribers_of}' if t.or_subscribers_of else ''
            )
            need = f' (need >= {t.subscribers})' if t.subscribers else ''
            out.append(
                f'topic {t.topic}: publishers {pubs} (need {t.publishers}), '
                f'subscribers {sub_text}{need}'
            )
    return out


RECORDER_STATUS = '/recorder/status'
#: the recorder drains its queues and writes the MCAP summary after SIGINT
RECORDER_STOP_SEQUENCE = ((signal.SIGINT, 20.0), (signal.SIGTERM, 3.0), (signal.SIGKILL, 2.0))


def recorder_missing(status: Mapping[str, Any] | None, topics: Sequence[str]) -> list[str]:
    """What the recorder has not got yet: ``topics`` it does not record, or a publisher it
    has not matched (``status``: its last ``/recorder/status`` document, None before one)."""
    if status is None:
        return ['recorder: no /recorder/status yet']
    rec = status.get('topics', {})
    out = [f'recorder: not recording {t} yet' for t in topics if t not in rec]
    for t, v in sorted(rec.items()):
        if v.get('matched', 0) < v.get('publishers', 0):
            out.append(
                f'recorder: {t} matched {v.get("matched")} of {v.get("publishers")} publishers'
            )
    return out


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


# --------------------------------------------------------------------------------------------
# the run's data
# --------------------------------------------------------------------------------------------


@dataclass
class RawSample:
    """A serialized ``/swarm/state`` message and its step; ``sample`` deserializes it."""

    step: int
    raw: bytes

    @property
    def sample(self) -> Any:
        from rclpy.serialization import deserialize_message

        from apf_swarm_msgs.msg import SwarmState

        from .conversions import swarm_state_arrays

        return swarm_state_arrays(deserialize_message(self.raw, SwarmState))


class StateAccumulator:
    """Collects ``/swarm/state`` samples (:class:`~apf_swarm_nodes.conversions.SwarmSample`).

    Lockstep: steps must be consecutive from 0; a gap counts its missing steps as dropped, a
    step that is not newer than the last one is counted as out of order and ignored. The run
    is complete when step ``steps - 1`` arrived. Realtime: steps advance with wall time and
    may skip; a sample whose step is not newer than the last one (the publish timer ran
    twice between two physics steps) is counted as repeated and ignored, so ``t`` increases
    strictly.
    """

    def __init__(self, mode: str, steps: int, record_every: int = 1) -> None:
        self.mode, self.steps, self.record_every = mode, int(steps), max(1, int(record_every))
        self.samples: list[Any] = []
        self.received = 0
        self.dropped = 0
        self.out_of_order = 0
        self.repeated = 0
        self.gaps: list[tuple[int, int]] = []
        self._last: Any = None
        self.last_step = -1
        self.last_time: float | None = None

    def add_raw(self, raw: bytes) -> None:
        """A serialized SwarmState: kept as bytes, deserialized only when needed (the
        bring-up shares the CPU with the swarm; deserializing every step costs ~0.4 ms)."""
        from .conversions import swarm_state_step

        try:
            step = swarm_state_step(raw)
        except ValueError:
            self.received += 1
            self.out_of_order += 1
            return
        self.add(RawSample(step, raw))

    def add(self, sample: Any) -> None:
        self.received += 1
        self.last_time = time.monotonic()
        if self.mode == 'lockstep':
            step = int(sample.step)
            if step <= self.last_step:
                self.out_of_order += 1
                return
            if step != self.last_step + 1:
                self.dropped += step - self.last_step - 1
                self.gaps.append((self.last_step + 1, step - 1))
            self.last_step = step
        else:
            # realtime: the publish timer may repeat a step the physics timer has not advanced
            step = int(sample.step)
            if step <= self.last_step:
                self.repeated += 1
                return
            self.last_step = step
        self._last = sample
        self.samples.append(sample)

    @property
    def last(self) -> Any:
        """The newest sample as arrays (a SwarmSample), or None."""
        s = self._last
        return s.sample if isinstance(s, RawSample) else s

    @property
    def complete(self) -> bool:
        """The plant's last state arrived: lockstep step ``steps - 1``; realtime the state
        at the end of the run (its physics step reaches ``steps``)."""
        return self.last_step >= (self.steps - 1 if self.mode == 'lockstep' else self.steps)

    def kept(self) -> list[Any]:
        """The samples of the trajectory, as arrays."""
        samples = self.samples
        if self.mode == 'lockstep' and self.record_every > 1:
            samples = [s for s in samples if int(s.step) % self.record_every == 0]
        return [s.sample if isinstance(s, RawSample) else s for s in samples]

    def trajectory(self) -> dict[str, Any] | None:
        """Arrays of the ``trajectory.npz`` schema, or None without samples."""
        import numpy as np

        kept = self.kept()
        if not kept:
            return None
        n = kept[0].x.shape[0]
        bad = [int(s.step) for s in kept if s.x.shape[0] != n]
        if bad:
            raise CliError(
                f'/swarm/state changed its number of trackers from {n} (steps '
                f'{bad[:5]}...); cannot build one trajectory'
            )
        return {
            't': np.array([s.t for s in kept], dtype=float),
            'x': np.stack([s.x for s in kept]),
            'v': np.stack([s.v for s in kept]),
            'u': np.stack([s.u for s in kept]),
            's': np.stack([s.s for s in kept]),
            'target_x': np.stack([s.target_x for s in kept]),
            'target_v': np.stack([s.target_v for s in kept]),
            # the per-sample arrays of a ROS run (runio.RUN_ARRAYS)
            'active': np.array([s.active or (True,) * n for s in kept], dtype=bool),
            'target_age': np.array([s.target_age for s in kept], dtype=float),
            'stale_inputs': np.array([s.stale_inputs for s in kept], dtype=int),
            'command_latency': np.array(
                [s.command_latency or (0.0,) * n for s in kept], dtype=float
            ),
        }

    def messages(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            'received': self.received,
            'dropped': self.dropped,
            'gaps': [list(g) for g in self.gaps[:20]],
            'out_of_order': self.out_of_order,
        }
        if self.mode == 'lockstep':
            out['expected'] = self.steps
        else:
            out['repeated'] = self.repeated
        return out


# --------------------------------------------------------------------------------------------
# configuration, isolation, command lines
# --------------------------------------------------------------------------------------------


def check_capacity(
    n_trackers: int,
    *,
    allow_overload: bool = False,
    per_process: int = 1,
    say: Callable[[str], None] | None = None,
) -> None:
    """Refuse more tracker processes than this machine runs (CliError naming the limit).

    The limit counts processes (``ceil(n_trackers / per_process)``) and comes from the
    machine's probe (:func:`apf_swarm_nodes.probe.process_limit`: CPU at the lowest rate and
    memory); a process of K trackers takes far less CPU and memory than K processes, but its
    trackers share one core. Without a probe (it failed) nothing is refused, with a warning."""
    from . import probe

    if allow_overload:
        return
    procs = -(-n_trackers // per_process)
    try:
        machine = probe.ensure(say=say)
    except (RuntimeError, OSError, ValueError, subprocess.TimeoutExpired) as exc:
        if say is not None:
            say(f'warning: {exc}; the tracker process limit is not known, none applied')
        return
    limit = probe.process_limit(machine)
    if procs > limit['processes'] and not allow_overload:
        raise CliError(
            f'n_trackers = {n_trackers} in {procs} processes is more than this '
            f'machine runs: its probe (`apf-swarm probe`) allows '
            f'{limit["processes"]} tracker processes ({limit["cpu"]} by CPU at '
            f'{probe.RATES[-1]:g} Hz, {limit["memory"]} by memory); use fewer '
            f'trackers, --trackers-per-process K to host several in one process, '
            f'or --allow-overload to start them anyway'
        )


def resolve_config(args: argparse.Namespace) -> SwarmConfig:
    """Preset or file, then ``--set``, then ``--n-trackers`` / ``--seed`` / ``--duration``."""
    return resolve(
        args.config,
        args.preset,
        args.sets,
        n_trackers=args.n_trackers,
        seed=args.seed,
        duration=args.duration,
    )


_FASTDDS_PORT_BASE, _FASTDDS_DOMAIN_GAIN = 7400, 250


def _bound_udp_ports() -> set[int]:
    ports: set[int] = set()
    with contextlib.suppress(psutil.Error, OSError):
        ports.update(c.laddr.port for c in psutil.net_connections('udp') if c.laddr)
    try:
        for entry in os.listdir('/dev/shm'):
            m = re.match(r'fastrtps_port(\d+)$', entry)
            if m:
                ports.add(int(m.group(1)))
    except OSError:
        pass
    return ports


def domain_looks_busy(domain: int, ports: set[int] | None = None) -> bool:
    """True when a UDP port (or Fast DDS shared-memory port) of the domain's range is in use."""
    ports = _bound_udp_ports() if ports is None else ports
    lo = _FASTDDS_PORT_BASE + _FASTDDS_DOMAIN_GAIN * domain
    return any(lo <= p < lo + _FASTDDS_DOMAIN_GAIN for p in ports)


#: how long a picked domain stays reserved for its picker [s]: long enough for the run it
#: was picked for to start its nodes, whose bound ports then mark it busy
DOMAIN_LEASE = 60.0


def _lease_dir() -> Path:
    base = os.environ.get('XDG_RUNTIME_DIR') or tempfile.gettempdir()
    return Path(base) / 'apf_swarm-domains'


def pick_domain_id(
    exclude: Iterable[int] = (), lo: int = 1, hi: int = 101, rng: random.Random | None = None
) -> int:
    """A random domain in ``[lo, hi]``, not in ``exclude``, preferring one nobody uses: no
    bound port of its range, and not picked in the last :data:`DOMAIN_LEASE` seconds by any
    process of this machine (a lease file, written under a lock, so two runs that pick at
    the same instant, before either has bound a port, get different domains)."""
    rng = rng or random.SystemRandom()
    excl = set(exclude)
    candidates = [d for d in range(lo, hi + 1) if d not in excl]
    rng.shuffle(candidates)
    leases = _lease_dir()
    try:
        leases.mkdir(parents=True, exist_ok=True)
        lock = open(leases / '.lock', 'w')  # noqa: SIM115 (held across the lease, closed below)
    except OSError:
        lock = None  # no lease files here: the ports decide alone
    try:
        if lock is not None:
            fcntl.flock(lock, fcntl.LOCK_EX)
        ports, now = _bound_udp_ports(), time.time()

        def leased(d: int) -> bool:
            try:
                return now - (leases / str(d)).stat().st_mtime < DOMAIN_LEASE
            except OSError:
                return False

        free = [d for d in candidates if not domain_looks_busy(d, ports)]
        d = next(
            (d for d in free if lock is None or not leased(d)), free[0] if free else candidates[0]
        )
        if lock is not None:
            (leases / str(d)).write_text(f'{os.getpid()}\n')
        return d
    finally:
        if lock is not None:
            lock.close()


def _env_domain() -> int | None:
    try:
        return int(os.environ.get('ROS_DOMAIN_ID', ''))
    except ValueError:
        return None


def executable_path(prefix: Path, name: str) -> Path:
    return prefix / 'lib' / PACKAGE / name


def package_prefix() -> Path:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        return Path(get_package_prefix(PACKAGE))
    except (PackageNotFoundError, KeyError, ValueError) as exc:
        raise CliError(
            f'package {PACKAGE} is not in the ament index ({exc}); build with '
            '`make setup` and `source scripts/activate.sh`'
        ) from None


def node_commands(
    prefix: Path,
    config_file: Path,
    n: int,
    mode: str,
    node_params: Sequence[str] = (),
    per_process: int = 1,
) -> list[tuple[str, list[str]]]:
    """(log name, argv) of every node process of the swarm.

    ``node_params`` (``NAME:=VALUE``) go to every node, e.g. ``executor:=events``.
    ``per_process`` > 1: the trackers are hosted that many to a process (executable
    ``trackers``, log names ``trackers_<first>-<last>``), each still its own node
    ``/uav_<i>/tracker`` with its own parameters.
    """
    cfg = str(config_file)
    extra = [a for p in node_params for a in ('-p', p)]

    def exe(name: str) -> str:
        return str(executable_path(prefix, name))

    cmds = [
        (
            'target',
            [
                exe('target'),
                '--ros-args',
                '--params-file',
                cfg,
                '-r',
                '__ns:=/target',
                '-r',
                '__node:=target',
                '-p',
                f'mode:={mode}',
                '-p',
                'wait_for_start:=true',
                *extra,
            ],
        ),
        (
            'plant',
            [
                exe('plant'),
                '--ros-args',
                '--params-file',
                cfg,
                '-r',
                '__node:=plant',
                '-p',
                f'mode:={mode}',
                '-p',
                'wait_for_start:=true',
                *extra,
            ],
        ),
    ]
    if per_process > 1:
        for first in range(1, n + 1, per_process):
            last = min(n, first + per_process - 1)
            cmds.append(
                (
                    f'trackers_{first}-{last}',
                    [
                        exe('trackers'),
                        '--uav-ids',
                        f'{first}-{last}',
                        '--ros-args',
                        '--params-file',
                        cfg,
                        '-p',
                        f'mode:={mode}',
                        *extra,
                    ],
                )
            )
        return cmds
    for i in range(1, n + 1):
        cmds.append(
            (
                f'tracker_{i}',
                [
                    exe('tracker'),
                    '--ros-args',
                    '--params-file',
                    cfg,
                    '-r',
                    f'__ns:=/uav_{i}',
                    '-r',
                    '__node:=tracker',
                    '-p',
                    f'uav_id:={i}',
                    '-p',
                    f'mode:={mode}',
                    *extra,
                ],
            )
        )
    return cmds


# --------------------------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------------------------


def node_netns(name: str, rules: Sequence[str] | None) -> str | None:
    """The network namespace a node process runs in: the first ``PATTERN=NETNS`` rule whose
    shell pattern matches its log name (``tracker_3``, ``trackers_1-2``, ``plant``), or None."""
    import fnmatch

    for rule in rules or ():
        pattern, _, ns = rule.partition('=')
        if fnmatch.fnmatchcase(name, pattern):
            return ns
    return None


def _netns_rule(text: str) -> str:
    pattern, sep, ns = text.partition('=')
    if not sep or not pattern or not ns:
        raise argparse.ArgumentTypeError(f'{text!r}: expected PATTERN=NETNS, e.g. tracker_*=h2')
    return text


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``swarm_up.py`` / ``apf-swarm up``."""
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument(
        '--preset',
        metavar='NAME',
        help='named preset (config/NAME.yaml): ' + ', '.join(preset_names()),
    )
    g.add_argument('--config', metavar='FILE', type=Path, help='ROS 2 parameter file')
    p.add_argument(
        '--set',
        metavar='KEY=VALUE',
        action='append',
        default=[],
        dest='sets',
        help='override a configuration key (repeatable), e.g. --set gamma=0.5',
    )
    p.add_argument('--n-trackers', type=int, metavar='N', help='number of tracker processes')
    p.add_argument(
        '--mode',
        choices=('lockstep', 'realtime'),
        default='lockstep',
        help='lockstep: simulated time, reproduces the simulator (default); '
        'realtime: wall-clock timers',
    )
    p.add_argument(
        '--duration',
        type=positive_float,
        metavar='S',
        help='simulated (lockstep) or wall (realtime) seconds',
    )
    p.add_argument('--seed', type=int, metavar='N')
    p.add_argument(
        '--domain-id',
        type=domain_id,
        metavar='N',
        help='ROS_DOMAIN_ID of the run (default: a random unused-looking one, 1..101)',
    )
    p.add_argument(
        '--discovery-range',
        choices=DISCOVERY_RANGES,
        default='LOCALHOST',
        help='ROS_AUTOMATIC_DISCOVERY_RANGE (default LOCALHOST)',
    )
    p.add_argument(
        '--record', action='store_true', help='also record a rosbag2 (MCAP) with the recorder node'
    )
    p.add_argument(
        '--trackers-per-process',
        type=positive_int,
        default=1,
        metavar='K',
        help='host the trackers K to a process (executable trackers; each still '
        'its own node with its own namespace and parameters); default 1',
    )
    p.add_argument(
        '--node-netns',
        type=_netns_rule,
        action='append',
        default=[],
        metavar='PATTERN=NETNS',
        help='run the node processes whose name matches PATTERN in that network '
        'namespace (`ip netns exec`; root): simulated hosts, see '
        'scripts/multihost.py; repeatable, first match wins',
    )
    p.add_argument(
        '--allow-overload',
        action='store_true',
        help="start more tracker processes than this machine's limit, which "
        'its probe derives (`apf-swarm probe`)',
    )
    p.add_argument(
        '--on-recorder-death',
        choices=('stop', 'continue'),
        default='stop',
        help='with --record: what a dying recorder does to the run (default stop; '
        'continue: fly on unrecorded, reindex the bag afterwards)',
    )
    p.add_argument(
        '--respawn',
        action='store_true',
        help='restart a node process that dies (counted in summary.json)',
    )
    p.add_argument(
        '--max-respawns',
        type=nonneg_int,
        default=3,
        metavar='K',
        help='with --respawn: give up (exit 3) after K restarts of one node (default 3)',
    )
    p.add_argument(
        '--ready-timeout',
        type=positive_float,
        default=30.0,
        metavar='S',
        help='how long to wait for every node and topic (default 30)',
    )
    p.add_argument(
        '--stall-timeout',
        type=positive_float,
        default=20.0,
        metavar='S',
        help='stop when no /swarm/state arrives for this long (default 20)',
    )
    p.add_argument(
        '--gains',
        choices=('auto', 'config'),
        default='auto',
        help='realtime: auto (default) replaces the controller gains by '
        '`apf-swarm design --control-rate` ones when the sampled-data '
        "prediction says the configuration's would not hold the formation "
        'at this size and rate; config flies them as given (warned)',
    )
    p.add_argument('--no-plots', action='store_true', help='skip the PNG figures')
    p.add_argument(
        '--node-param',
        action='append',
        default=[],
        metavar='NAME:=VALUE',
        dest='node_params',
        help='a node parameter for every node (repeatable), e.g. executor:=events, inputs:=odom',
    )
    p.add_argument('--out', type=Path, required=True, metavar='DIR')


def build_parser(prog: str = 'swarm_up.py') -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=prog,
        description='Bring up the ROS 2 swarm (target, plant, one tracker process '
        'per UAV), run it, and write trajectory.npz, summary.json, logs and figures.',
    )
    add_arguments(p)
    return p


# --------------------------------------------------------------------------------------------
# the bring-up itself
# --------------------------------------------------------------------------------------------


class _Stop(Exception):  # noqa: N818 (a control-flow signal, not an error)
    """Ends the run early with an exit code and a status word."""

    def __init__(self, code: int, status: str, message: str = '') -> None:
        super().__init__(message)
        self.code, self.status, self.message = code, status, message


class _Signals:
    """SIGINT / SIGTERM set a flag (the loops poll it); restored on exit."""

    def __init__(self) -> None:
        self.received: list[int] = []
        self._old: dict[int, Any] = {}

    def _handler(self, signum: int, frame: Any) -> None:
        self.received.append(signum)

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(ValueError):  # not the main thread: nothing to install
                self._old[sig] = signal.signal(sig, self._handler)

    def restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()

    @property
    def first(self) -> int | None:
        return self.received[0] if self.received else None


class Bringup:
    """One run; see the module docstring. :meth:`execute` returns the exit code."""

    def __init__(
        self,
        args: argparse.Namespace,
        cfg: SwarmConfig,
        *,
        prog: str,
        stream: TextIO | None = None,
    ) -> None:
        self.args, self.cfg, self.prog = args, cfg, prog
        # realtime: what the probe implies, the prediction before the run, scheduled gains
        self.capacity: dict[str, Any] | None = None
        self.prediction: Any = None
        self.gains_scheduled: dict[str, Any] = {}
        self.err = stream if stream is not None else sys.stderr
        self.mode: str = args.mode
        self.node_params: list[str] = list(getattr(args, 'node_params', []) or [])
        self.out: Path = args.out
        self.n = cfg.n_trackers
        self.group = ProcessGroup()
        #: the recorder: started first, stopped last, given time to close the bag
        self.rec_group = ProcessGroup(RECORDER_STOP_SEQUENCE)
        self.recorder_lost: dict[str, int] = {}  # recorder died, run went on: its exit code
        self.rec_status: dict[str, Any] | None = None
        self.signals = _Signals()
        self.acc = StateAccumulator(self.mode, cfg.steps, cfg.record_every)
        self.domain_id: int | None = None
        self.node = None
        self.executor = None
        self.state_sub = None
        self.start_pub = None
        self.t_launch = self.t_start = self.t_end = None
        self.stop_how: dict[str, str] = {}
        self.stop_seconds = 0.0
        self.leftovers: list[tuple[str, int]] = []
        self.warned: set[str] = set()

    # --- messages -------------------------------------------------------------------------
    def say(self, text: str) -> None:
        self.err.write(f'{self.prog}: {text}\n')
        self.err.flush()

    def warn_once(self, key: str, text: str) -> None:
        if key not in self.warned:
            self.warned.add(key)
            self.say(f'warning: {text}')

    # --- set-up ---------------------------------------------------------------------------
    def realtime_check(self) -> None:
        """Realtime: the sampled-data prediction before the run (printed, and kept for
        summary.json); with ``--gains auto`` a failing one is replaced by designed gains."""
        from apf_swarm_core.sampled import predict, schedule_gains

        from . import probe

        cfg = self.cfg
        try:
            machine = probe.ensure(say=self.say)
        except (RuntimeError, OSError, ValueError, subprocess.TimeoutExpired) as exc:
            self.say(
                f'warning: {exc}; assuming {REALTIME_RATE:g} Hz and '
                f'{DEFAULT_LATENCY * 1e3:g} ms of latency'
            )
            machine = None
        measured = (
            probe.derive(machine, self.n, cfg.control_rate or None)
            if machine
            else {'rate': cfg.control_rate or REALTIME_RATE, 'latency': None, 'capacity': {}}
        )
        self.capacity = measured
        if cfg.control_rate <= 0:
            cfg = cfg.replace(control_rate=measured['rate'])
            self.say(
                f'control rate {measured["rate"]:g} Hz for {self.n} trackers on this '
                f'machine (`apf-swarm probe`)'
            )
        latency = cfg.latency or measured['latency'] or DEFAULT_LATENCY
        fits = measured['capacity'].get(f'{cfg.control_rate:g}')
        if fits is not None and self.n > fits:
            self.say(
                f'warning: {self.n} trackers at {cfg.control_rate:g} Hz are more than '
                f"the {fits} that fit in {probe.CPU_BUDGET:.0%} of this machine's cores "
                f'(`apf-swarm probe`): expect late commands; a lower rate (--set '
                f'control_rate=HZ: '
                + ', '.join(f'{v} at {k} Hz' for k, v in measured['capacity'].items())
                + ') or fewer trackers'
            )
        if getattr(self.args, 'gains', 'auto') == 'auto':
            cfg, pred, gains, warnings = schedule_gains(cfg, latency=latency)
        else:
            pred = predict(cfg, latency=latency)
            gains, warnings = None, list(pred.warnings)
        if gains:
            self.say(
                'scheduled gains for '
                f'{cfg.n_trackers} trackers at '
                f'{cfg.control_rate:g} Hz, {latency * 1e3:g} ms (the '
                "configuration's are predicted to lose the formation; "
                '--gains config keeps them): '
                + ', '.join(
                    f'{k} = {v:.4g}' if isinstance(v, float) else f'{k} = {v}'
                    for k, v in gains.items()
                )
            )
            self.gains_scheduled = gains
        for w in warnings:
            self.say(f'warning: {w}')
        self.cfg = cfg
        self.prediction = pred

    def prepare(self) -> None:
        """Checks that need no process: executables, recorder, output directory, config."""
        import yaml

        if self.mode == 'realtime':
            self.realtime_check()
        elif self.cfg.control_rate > 0:
            raise CliError(
                f'control_rate = {self.cfg.control_rate:g} Hz: lockstep commands '
                'every step of dt; use --mode realtime, or --set control_rate=0'
            )
        prefix = package_prefix()
        names = [
            'target',
            'plant',
            'tracker' if self.args.trackers_per_process == 1 else 'trackers',
        ]
        if self.args.record:
            names.append('recorder')
            if (self.out / 'bag').exists():
                raise CliError(
                    f'--record: {self.out / "bag"} exists already; a bag is never '
                    'overwritten: choose a new --out directory'
                )
        for name in names:
            path = executable_path(prefix, name)
            if not (path.is_file() and os.access(path, os.X_OK)):
                raise CliError(
                    f'node executable {path} not found; build the workspace with `make setup`'
                )
        self.prefix = prefix
        (self.out / 'logs').mkdir(parents=True, exist_ok=True)
        self.config_file = self.out / 'config.yaml'
        self.config_file.write_text(yaml.safe_dump(to_ros_params(self.cfg), sort_keys=False))

    def isolate(self) -> None:
        """Domain id and discovery range into os.environ (before rclpy.init; children inherit)."""
        if self.args.domain_id is not None:
            self.domain_id = self.args.domain_id
        else:
            own = _env_domain()
            self.domain_id = pick_domain_id(exclude=[own] if own is not None else [])
        os.environ['ROS_DOMAIN_ID'] = str(self.domain_id)
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = self.args.discovery_range
        os.environ.pop('ROS_LOCALHOST_ONLY', None)  # deprecated; would fight the range
        # every ROS log file of the run (this node's and the children's) under DIR/logs/ros
        os.environ['ROS_LOG_DIR'] = str((self.out / 'logs' / 'ros').resolve())

    def child_env(self) -> dict[str, str]:
        env = dict(os.environ)
        env.setdefault('PYTHONUNBUFFERED', '1')
        env.setdefault('RCUTILS_COLORIZED_OUTPUT', '0')
        return env

    def launch(self) -> None:
        env = self.child_env()
        cmds = node_commands(
            self.prefix,
            self.config_file.resolve(),
            self.n,
            self.mode,
            self.node_params,
            per_process=self.args.trackers_per_process,
        )
        self.t_launch = time.monotonic()
        if self.args.record:
            # first, so that it subscribes to every topic as soon as its publisher appears
            rec = Child(
                'recorder',
                [
                    str(executable_path(self.prefix, 'recorder')),
                    '--ros-args',
                    '-r',
                    '__node:=recorder',
                    '-p',
                    f'mode:={self.mode}',
                    '-p',
                    f'output:={(self.out / "bag").resolve()}',
                    '-p',
                    f'config_file:={self.config_file.resolve()}',
                    *[a for p in self.node_params for a in ('-p', p)],
                ],
                self.out / 'logs' / 'recorder.log',
                env,
            )
            self.rec_group.add(rec)
            self.rec_group.start_all()
        for name, cmd in cmds:
            ns = node_netns(name, self.args.node_netns)
            # a simulated host (scripts/multihost.py)
            argv = cmd if ns is None else ['ip', 'netns', 'exec', ns, *cmd]
            self.group.add(Child(name, argv, self.out / 'logs' / f'{name}.log', env))
        self.group.start_all()
        self.say(
            f'started {len(cmds) + len(self.rec_group.children)} processes '
            f'on ROS_DOMAIN_ID={self.domain_id} '
            f'({self.args.discovery_range}), {self.mode}, {self.n} trackers, '
            f'logs in {self.out / "logs"}'
        )

    def init_ros(self) -> None:
        import rclpy
        from rclpy.experimental import EventsExecutor
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import Empty

        from apf_swarm_msgs.msg import SwarmState

        from .node_common import START_QOS, STATE_QOS, SWARM_START, SWARM_STATE

        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('swarm_up')
        # the events executor costs less CPU per /swarm/state sample than the single-
        # threaded one, and the bring-up shares the cores with the swarm
        # (bench/bench_graph.py compares the executors)
        self.executor = EventsExecutor()
        self.executor.add_node(self.node)
        self.state_sub = self.node.create_subscription(
            SwarmState, SWARM_STATE, self.acc.add_raw, STATE_QOS, raw=True
        )
        if self.args.record:
            import json

            from std_msgs.msg import String

            def on_status(msg: Any) -> None:
                with contextlib.suppress(ValueError):
                    self.rec_status = json.loads(msg.data)

            self.node.create_subscription(String, RECORDER_STATUS, on_status, START_QOS)
        self.start_pub = self.node.create_publisher(Empty, SWARM_START, START_QOS)
        self._empty_msg = Empty

    # --- supervision ----------------------------------------------------------------------
    def check_signals(self) -> None:
        sig = self.signals.first
        if sig is not None:
            raise _Stop(
                EXIT_INTERRUPTED, 'interrupted', f'interrupted by {signal.Signals(sig).name}'
            )

    def supervise(self) -> None:
        for child, rc in self.rec_group.poll():
            if child.name in self.recorder_lost:
                continue
            self.say(child.death_report(rc))
            self.recorder_lost[child.name] = rc
            if self.args.on_recorder_death == 'continue':
                self.say(
                    f'{child.name} died ({_describe_rc(rc)}); the run continues without '
                    f'recording (--on-recorder-death continue); `apf-swarm bag reindex '
                    f'{self.out / "bag"}` recovers what it flushed'
                )
                continue
            raise _Stop(
                EXIT_CHILD_DIED,
                'child_died',
                f'{child.name} died ({_describe_rc(rc)}); stopping the run (a restarted '
                f'recorder could not continue the bag; `apf-swarm bag reindex '
                f'{self.out / "bag"}` recovers what it flushed; --on-recorder-death '
                f'continue keeps the swarm flying)',
            )
        for child, rc in self.group.poll():
            self.say(child.death_report(rc))
            if not self.args.respawn:
                raise _Stop(
                    EXIT_CHILD_DIED,
                    'child_died',
                    f'{child.name} died ({_describe_rc(rc)}); stopping the run',
                )
            why_not = self.not_respawnable(child.name)
            if why_not:
                raise _Stop(
                    EXIT_CHILD_DIED,
                    'child_died',
                    f'{child.name} died ({_describe_rc(rc)}); stopping the run: {why_not}',
                )
            if child.respawns >= self.args.max_respawns:
                raise _Stop(
                    EXIT_CHILD_DIED,
                    'child_died',
                    f'{child.name} died ({_describe_rc(rc)}) after '
                    f'{child.respawns} respawns (--max-respawns {self.args.max_respawns}); '
                    'stopping the run',
                )
            child.start()
            self.say(
                f'respawned {child.name} (pid {child.pid}, respawn {child.respawns} of at '
                f'most {self.args.max_respawns})'
            )

    def not_respawnable(self, name: str) -> str:
        """Why a dead node must not be restarted ('' when it may be): the plant holds the
        state of the whole swarm, and a realtime target restarts its trajectory from t = 0."""
        if name == 'plant':
            return (
                'the plant holds the state of every UAV; a restarted plant would start '
                'the world over, so it is never respawned'
            )
        if name == 'target' and self.mode == 'realtime':
            return (
                'a restarted realtime target would fly its trajectory again from t = 0; '
                "only lockstep targets (driven by the plant's requests) are respawned"
            )
        return ''

    def spin(self, timeout: float) -> None:
        self.executor.spin_once(timeout_sec=timeout)

    # --- the graph ------------------------------------------------------------------------
    def missing(self) -> list[str]:
        node = self.node
        present = {
            (ns.rstrip('/') + '/' + name) for name, ns in node.get_node_names_and_namespaces()
        }
        nodes, topics = expected_graph(
            self.n,
            self.mode,
            input_readers(self.n, self.mode, self.args.trackers_per_process, self.node_params),
        )
        if self.args.record:
            nodes = [*nodes, '/recorder']
        counts = {
            t.topic: (node.count_publishers(t.topic), node.count_subscribers(t.topic))
            for t in topics
        }
        miss = graph_missing(present, counts, nodes, topics)
        for t in topics:
            if counts[t.topic][0] > t.publishers:
                self.warn_once(
                    'pubs' + t.topic,
                    f'{t.topic} has {counts[t.topic][0]} publishers (expected '
                    f'{t.publishers}): another graph on ROS_DOMAIN_ID='
                    f'{self.domain_id}, or a respawned node not yet forgotten?',
                )
        # our own endpoints: matched counts, not mere discovery
        nstate = self.state_sub.get_publisher_count()
        if nstate < 1:
            miss.append(
                f"topic /swarm/state: this bring-up's subscription matched to "
                f'{nstate} publishers (need 1: the plant)'
            )
        # the plant waits for the start in both modes; the target only in realtime (in
        # lockstep it is driven by the plant's /target/request)
        nstart = self.start_pub.get_subscription_count()
        want, who = (2, 'plant, target') if self.mode == 'realtime' else (1, 'plant')
        if nstart < want:
            miss.append(
                f'topic /swarm/start: matched subscribers {nstart} (need >= {want}: {who})'
            )
        if self.args.record:
            miss += recorder_missing(
                self.rec_status, [t.topic for t in topics if t.publishers and not t.optional]
            )
        return miss

    def wait_ready(self) -> None:
        t0 = time.monotonic()
        deadline = t0 + self.args.ready_timeout
        last_check, last_report = 0.0, t0
        miss = ['(not checked yet)']
        while True:
            self.spin(0.05)
            self.check_signals()
            self.supervise()
            now = time.monotonic()
            if now - last_check >= 0.1:
                last_check = now
                miss = self.missing()
                if not miss:
                    return
            if now - last_report >= 5.0:
                last_report = now
                self.say(
                    f'waiting for the graph ({now - t0:.0f} s of '
                    f'{self.args.ready_timeout:g}): {len(miss)} missing, e.g. {miss[0]}'
                )
            if now >= deadline:
                raise _Stop(
                    EXIT_BAD_INPUT,
                    'not_ready',
                    f'the ROS graph was not complete after {self.args.ready_timeout:g} s '
                    f'(--ready-timeout, ROS_DOMAIN_ID={self.domain_id}); '
                    f'{len(miss)} never appeared:\n'
                    + ''.join(f'    {m}\n' for m in miss)
                    + f'  node logs: {self.out / "logs"}',
                )

    # --- the run --------------------------------------------------------------------------
    def progress_line(self, rate: float) -> str:
        s = self.acc.last
        dur = self.cfg.duration
        if s is None:
            return (
                f'waiting for /swarm/state ({time.monotonic() - self.t_start:.1f} s since start)'
            )
        fe = 'n/a' if not math.isfinite(s.formation_error) else f'{s.formation_error:.3f} m'
        unit = 'steps/s' if self.mode == 'lockstep' else 'msgs/s'
        return (
            f't {s.t:7.2f}/{dur:g} s | centroid err {s.centroid_error:.3f} m | formation err '
            f'{fe} | missed {s.missed_deadlines} stale {s.stale_inputs} rejected '
            f'{s.rejected_inputs} | {rate:,.0f} {unit} | dropped {self.acc.dropped}'
        )

    def run_loop(self) -> None:
        self.start_pub.publish(self._empty_msg())
        self.t_start = time.monotonic()
        self.say(f'graph ready after {self.t_start - self.t_launch:.2f} s; published /swarm/start')
        last_progress = self.t_start
        last_poll = 0.0
        prev_step, prev_recv = 0, 0
        while True:
            self.spin(0.05)
            now = time.monotonic()
            self.check_signals()
            if now - last_poll >= 0.1:
                last_poll = now
                self.supervise()
            if self.acc.complete:
                return
            # realtime: the plant's clock starts once every tracker commands, so the run
            # ends with its final state; a plant that never gets there is cut off a stall
            # timeout after the duration
            if (
                self.mode == 'realtime'
                and now - self.t_start >= self.cfg.duration + self.args.stall_timeout
            ):
                self.say(
                    f'warning: no final state from the plant {self.args.stall_timeout:g} '
                    f's after the duration; stopping'
                )
                return
            last_msg = self.acc.last_time if self.acc.last_time is not None else self.t_start
            if now - last_msg >= self.args.stall_timeout:
                what = (
                    'no /swarm/state message at all'
                    if self.acc.received == 0
                    else f'no /swarm/state message after step {self.acc.last_step}'
                )
                raise _Stop(
                    EXIT_STALLED,
                    'stalled',
                    f'{what} for {self.args.stall_timeout:g} s (--stall-timeout); '
                    f'stopping. Node logs: {self.out / "logs"}',
                )
            if now - last_progress >= 1.0:
                if self.mode == 'lockstep':
                    rate = (self.acc.last_step + 1 - prev_step) / (now - last_progress)
                    prev_step = self.acc.last_step + 1
                else:
                    rate = (self.acc.received - prev_recv) / (now - last_progress)
                    prev_recv = self.acc.received
                last_progress = now
                self.say(self.progress_line(rate))

    def drain(self, seconds: float = 0.2) -> None:
        """Take what is already queued (realtime end) without waiting for more."""
        end = time.monotonic() + seconds
        before = -1
        while time.monotonic() < end and before != self.acc.received:
            before = self.acc.received
            self.spin(0.02)

    # --- shutdown and outputs -------------------------------------------------------------
    def stop_children(self) -> None:
        t0 = time.monotonic()
        self.stop_how = self.group.stop_all(hurry=lambda: len(self.signals.received))
        # the recorder last: it takes what is still queued and closes the bag
        self.stop_how.update(self.rec_group.stop_all(hurry=lambda: len(self.signals.received)))
        self.stop_seconds = time.monotonic() - t0
        self.leftovers = self.group.leftovers() + self.rec_group.leftovers()
        by: dict[str, list[str]] = {}
        for name, how in self.stop_how.items():
            by.setdefault(how, []).append(name)
        detail = ', '.join(f'{len(v)} {k}' for k, v in by.items())
        self.say(f'stopped {len(self.stop_how)} processes in {self.stop_seconds:.2f} s ({detail})')
        for how in ('SIGTERM', 'SIGKILL', 'not stopped'):
            if how in by:
                self.say(f'warning: needed {how} for: {", ".join(by[how])}')
        if self.leftovers:
            self.say(
                'error: processes left behind: '
                + ', '.join(f'{n} pid {p}' for n, p in self.leftovers)
            )

    def shutdown_ros(self) -> None:
        import rclpy

        if self.executor is not None:
            self.executor.shutdown(timeout_sec=1.0)
            self.executor = None
        if self.node is not None:
            self.node.destroy_node()
            self.node = None
        rclpy.try_shutdown()

    def run_fields(self, status: str) -> dict[str, Any]:
        last = self.acc.last
        run_s = (self.t_end - self.t_start) if self.t_start is not None else 0.0
        return {
            'status': status,
            'mode': self.mode,
            'domain_id': self.domain_id,
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
                'run': round(run_s, 3),
                'shutdown': round(self.stop_seconds, 3),
                'rate': round(len(self.acc.samples) / run_s, 1) if run_s > 0 else None,
            },
            'stopped_by': self.stop_how,
            **(
                {
                    'recording': {
                        **recording_fields(self.out / 'bag'),
                        **(
                            {'recorder_died': _describe_rc(list(self.recorder_lost.values())[-1])}
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
        from .runio import format_summary, run_summary, write_run

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
            from . import plots

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

    def predicted(self, traj: dict[str, Any]) -> dict[str, Any]:
        """Realtime: the run judged by flight next to its headless emulation at the same
        rate with the latencies the plant measured (and the prediction before the run)."""
        import numpy as np
        from apf_swarm_core.metrics import flight
        from apf_swarm_core.simulator import design_pair_sets, simulate

        pairs = design_pair_sets(self.cfg)
        lat = np.asarray(traj.get('command_latency', np.zeros((0,))), dtype=float).ravel()
        lat = lat[(lat > 0) & np.isfinite(lat)]
        out: dict[str, Any] = {
            'before_run': self.prediction.to_dict(),
            'gains_scheduled': self.gains_scheduled,
            'machine': self.capacity,
            'run': flight(traj, pairs),
        }
        if lat.size:
            out['latency'] = {
                q: round(float(np.quantile(lat, v)), 6)
                for q, v in (('p50', 0.5), ('p90', 0.9), ('p99', 0.99))
            }
            emu_cfg = self.cfg.replace(
                duration=float(traj['t'][-1] - traj['t'][0]) or self.cfg.duration,
                latency=float(np.median(lat)),
            )
            emu = simulate(emu_cfg, latency_samples=lat)
            out['emulation'] = flight(emu.trajectory, pairs)
            out['latency_samples'] = np.round(lat[:: max(1, lat.size // 2000)], 6).tolist()
        return out

    # --- everything -----------------------------------------------------------------------
    def execute(self) -> int:
        self.prepare()
        self.isolate()
        code, status, message = EXIT_OK, 'completed', ''
        self.signals.install()
        try:
            try:
                self.init_ros()
                self.launch()
                self.check_signals()
                self.wait_ready()
                self.run_loop()
                if self.mode == 'realtime':
                    self.drain()
                self.t_end = time.monotonic()
            except _Stop as stop:
                self.t_end = time.monotonic()
                code, status, message = stop.code, stop.status, stop.message
                self.say(('error: ' if code not in (EXIT_INTERRUPTED,) else '') + message)
            finally:
                if self.t_end is None:
                    self.t_end = time.monotonic()
                try:
                    self.stop_children()
                finally:
                    self.shutdown_ros()
        finally:
            self.signals.restore()
        if self.leftovers and code == EXIT_OK:
            code, status = EXIT_CHILD_DIED, 'leftover_processes'
        if code == EXIT_OK and self.mode == 'lockstep' and self.acc.dropped:
            code, status = EXIT_LOST_SAMPLES, 'lost_samples'
            self.say(
                f'error: {self.acc.dropped} /swarm/state samples were lost; the trajectory '
                'has gaps (a starved or paused bring-up: rerun on a quieter machine)'
            )
        if status in ('not_ready',):
            return code
        if self.t_start is not None:
            self.write_outputs(status)
        return code


def run(args: argparse.Namespace, prog: str = 'swarm_up') -> int:
    """Run a bring-up from parsed arguments (:func:`add_arguments`); returns the exit code.

    Raises :class:`~apf_swarm_core.errors.ApfSwarmError` for bad input (before anything
    starts); the caller prints it and exits 2.
    """
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # a hung run says where
    cfg = resolve_config(args)
    check_capacity(
        cfg.n_trackers,
        allow_overload=args.allow_overload,
        per_process=args.trackers_per_process,
        say=lambda m: print(f'{prog}: {m}', file=sys.stderr, flush=True),
    )
    return Bringup(args, cfg, prog=prog).execute()


def main(argv: Sequence[str] | None = None, prog: str = 'swarm_up.py') -> int:
    """Entry point of ``scripts/swarm_up.py``."""
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    try:
        return run(args, prog=prog)
    except ApfSwarmError as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        print(f'{prog}: error: {exc.strerror or exc}: {exc.filename or ""}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f'{prog}: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == '__main__':
    sys.exit(main())
