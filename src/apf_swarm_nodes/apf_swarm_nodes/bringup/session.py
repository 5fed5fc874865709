"""The run itself (:class:`Bringup`): start, wait for the graph, publish the start,
accumulate, supervise, stop, write."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from apf_swarm_core.config import (
    DEFAULT_LATENCY,
    REALTIME_RATE,
    SwarmConfig,
    to_ros_params,
)

from ..errors import CliError
from ..samples import StateAccumulator
from .commands import executable_path, node_commands, node_netns, package_prefix
from .graph import (
    RECORDER_STATUS,
    RECORDER_STOP_SEQUENCE,
    expected_graph,
    graph_missing,
    input_readers,
    recorder_missing,
    recording_fields,
)
from .isolation import env_domain, pick_domain_id
from .processes import (
    EXIT_BAD_INPUT,
    EXIT_CHILD_DIED,
    EXIT_INTERRUPTED,
    EXIT_LOST_SAMPLES,
    EXIT_OK,
    EXIT_STALLED,
    Child,
    ProcessGroup,
    describe_rc,
)

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
        # rclpy objects, made by run() once rclpy is imported (this module does not import it)
        self.node: Any = None
        self.executor: Any = None
        self.state_sub: Any = None
        self.start_pub: Any = None
        # monotonic times of the launch, the start and the end of the run [s]
        self.t_launch: Any = None
        self.t_start: Any = None
        self.t_end: Any = None
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

        from .. import probe

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
            own = env_domain()
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

        from ..node_common import START_QOS, STATE_QOS, SWARM_START, SWARM_STATE

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
                    f'{child.name} died ({describe_rc(rc)}); the run continues without '
                    f'recording (--on-recorder-death continue); `apf-swarm bag reindex '
                    f'{self.out / "bag"}` recovers what it flushed'
                )
                continue
            raise _Stop(
                EXIT_CHILD_DIED,
                'child_died',
                f'{child.name} died ({describe_rc(rc)}); stopping the run (a restarted '
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
                    f'{child.name} died ({describe_rc(rc)}); stopping the run',
                )
            why_not = self.not_respawnable(child.name)
            if why_not:
                raise _Stop(
                    EXIT_CHILD_DIED,
                    'child_died',
                    f'{child.name} died ({describe_rc(rc)}); stopping the run: {why_not}',
                )
            if child.respawns >= self.args.max_respawns:
                raise _Stop(
                    EXIT_CHILD_DIED,
                    'child_died',
                    f'{child.name} died ({describe_rc(rc)}) after '
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
        from ..runio import format_summary, run_summary, write_run

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
            from .. import plots

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
