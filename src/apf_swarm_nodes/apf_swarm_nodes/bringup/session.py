"""The run itself (:class:`Bringup`): start, wait for the graph, publish the start,
accumulate, supervise, stop, write."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from apf_swarm_core.config import (
    SwarmConfig,
    to_ros_params,
)

from ..analysis.samples import StateAccumulator
from ..errors import CliError
from .commands import executable_path, node_commands, node_netns, package_prefix
from .graph import (
    RECORDER_STOP_SEQUENCE,
)
from .graph_watch import GraphWatch
from .isolation import env_domain, pick_domain_id
from .outputs import RunOutputs
from .prediction import RealtimePrediction
from .processes import (
    EXIT_CHILD_DIED,
    EXIT_INTERRUPTED,
    EXIT_LOST_SAMPLES,
    EXIT_OK,
    EXIT_STALLED,
    Child,
    ProcessGroup,
    StopRun,
    describe_rc,
)

# --------------------------------------------------------------------------------------------
# the bring-up itself
# --------------------------------------------------------------------------------------------


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


class Bringup(GraphWatch, RealtimePrediction, RunOutputs):
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

    # --- supervision ----------------------------------------------------------------------
    def check_signals(self) -> None:
        sig = self.signals.first
        if sig is not None:
            raise StopRun(
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
            raise StopRun(
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
                raise StopRun(
                    EXIT_CHILD_DIED,
                    'child_died',
                    f'{child.name} died ({describe_rc(rc)}); stopping the run',
                )
            why_not = self.not_respawnable(child.name)
            if why_not:
                raise StopRun(
                    EXIT_CHILD_DIED,
                    'child_died',
                    f'{child.name} died ({describe_rc(rc)}); stopping the run: {why_not}',
                )
            if child.respawns >= self.args.max_respawns:
                raise StopRun(
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

    # --- the graph ------------------------------------------------------------------------
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
                raise StopRun(
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
            except StopRun as stop:
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
