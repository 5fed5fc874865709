"""One run (:class:`Bringup`): set up, launch, wait for the graph, run (the loop between
``/swarm/start`` and the end, with its progress line), stop, write; its parts are in
:mod:`.startup`, :mod:`.graph_watch`, :mod:`.supervision`, :mod:`.flight_check`, :mod:`.outputs`.
"""

from __future__ import annotations

import math
import os
import random
import sys
import time
from typing import Any

from ..analysis.samples import StateAccumulator
from ..lifetime import describe_rc
from .commands import Plan
from .flight_check import FlightCheck
from .graph_watch import GraphWatch
from .outputs import recording_fields, write_outputs
from .processes import (
    EXIT_CHILD_DIED,
    EXIT_INTERRUPTED,
    EXIT_LOST_SAMPLES,
    EXIT_OK,
    EXIT_STALLED,
    StopRun,
)
from .startup import Startup
from .supervision import Signals, Supervisor

__all__ = ['Bringup']


class Bringup:
    """One run (see the module docstring); :meth:`execute` returns the exit code."""

    def __init__(self, plan: Plan, *, prog: str) -> None:
        self.plan, self.prog = plan, prog
        #: the configuration flown (realtime: the flight check's), known once prepared
        self.cfg = plan.cfg
        self.signals = Signals()
        self.sup = Supervisor(plan, self.signals, self.say)
        self.acc = StateAccumulator(plan.mode, plan.cfg.steps, plan.cfg.record_every)
        self.graph = GraphWatch(plan, self.acc, self.say)
        self.flight = FlightCheck(plan, self.say)
        #: the run's identity (the nodes' ``run`` parameter), random, never 0
        self.run_id = random.getrandbits(62) + 1
        self.setup = Startup(plan, self.run_id, self.sup, self.flight, self.say)
        # monotonic times of this bring-up's start, the start and the end of the run [s]
        self.t_begin = time.monotonic()
        self.t_start: Any = None
        self.t_end: Any = None
        #: ``--view``: the live view (:class:`~apf_swarm_nodes.view.LiveView`)
        self.view: Any = None

    def say(self, text: str) -> None:
        """Print a line of the bring-up on stderr."""
        print(f'{self.prog}: {text}', file=sys.stderr, flush=True)

    def between(self) -> None:
        """What the bring-up checks while it waits: signals, then its processes."""
        self.sup.check_signals()
        self.sup.supervise()

    def progress_line(self, rate: float) -> str:
        """The once-a-second line of the run; ``rate``: steps/s (lockstep) or msgs/s."""
        s = self.acc.last
        dur = self.cfg.duration
        if s is None:
            return (
                f'waiting for /swarm/state ({time.monotonic() - self.t_start:.1f} s since start)'
            )
        fe = 'n/a' if not math.isfinite(s.formation_error) else f'{s.formation_error:.3f} m'
        unit = 'steps/s' if self.plan.mode == 'lockstep' else 'msgs/s'
        return (
            f't {s.t:7.2f}/{dur:g} s | centroid err {s.centroid_error:.3f} m | formation err '
            f'{fe} | missed {s.missed_deadlines} stale {s.stale_inputs} rejected '
            f'{s.rejected_inputs} | {rate:,.0f} {unit} | dropped {self.acc.dropped}'
        )

    def run_loop(self) -> None:
        """Publish ``/swarm/start`` and take the states until the run completes or stalls."""
        plan, acc = self.plan, self.acc
        self.graph.publish_start()
        self.t_start = time.monotonic()
        self.say(
            f'graph ready after {self.t_start - self.setup.t_launch:.2f} s; published /swarm/start'
        )
        last_progress = self.t_start
        last_poll = 0.0
        prev = 0  # steps (lockstep) or messages (realtime) at the last progress line
        while True:
            self.graph.spin(0.05)
            now = time.monotonic()
            self.sup.check_signals()
            if now - last_poll >= 0.1:
                last_poll = now
                self.sup.supervise()
            if acc.complete:
                return
            # realtime: a plant that never sends its final state is cut off
            if plan.mode == 'realtime' and now - self.t_start >= (
                self.cfg.duration + plan.stall_timeout
            ):
                self.say(
                    f'warning: no final state from the plant {plan.stall_timeout:g} '
                    f's after the duration; stopping'
                )
                return
            last_msg = acc.last_time if acc.last_time is not None else self.t_start
            if now - last_msg >= plan.stall_timeout:
                what = (
                    'no /swarm/state message at all'
                    if acc.received == 0
                    else f'no /swarm/state message after step {acc.last_step}'
                )
                raise StopRun(
                    EXIT_STALLED,
                    'stalled',
                    f'{what} for {plan.stall_timeout:g} s (--stall-timeout); '
                    f'stopping. Node logs: {plan.out / "logs"}',
                )
            if now - last_progress >= 1.0:
                count = acc.last_step + 1 if plan.mode == 'lockstep' else acc.received
                rate = (count - prev) / (now - last_progress)
                prev, last_progress = count, now
                self.say(self.progress_line(rate))

    def start_view(self) -> None:
        """``--view``: serve the newest ``/swarm/state`` sample to Foxglove (a busy port is
        bad input, found before any process starts)."""
        if self.plan.view is None:
            return
        from apf_swarm_core.formation import design_pair_sets

        from ..view import LiveView

        self.view = LiveView(
            host=self.plan.view_host,
            port=self.plan.view,
            designs=design_pair_sets(self.cfg),
            stale_after=self.plan.stale_after,
        )
        self.view.follow(lambda: self.acc.newest)
        self.say(f'view: {self.view.url} (Foxglove: Open connection, Foxglove WebSocket)')

    def execute(self) -> int:
        """The whole run; returns the exit code."""
        # every process of the run names its bring-up (for `apf-swarm clean`)
        from ..dds.cleanup import BRINGUP_ENV, bringup_mark

        os.environ[BRINGUP_ENV] = bringup_mark()
        self.setup.start_zygote()  # its imports overlap the preparation
        try:
            self.cfg = self.setup.prepare()
            return self.execute_prepared()
        finally:
            self.setup.close()

    def execute_prepared(self) -> int:
        """From the isolation to the outputs; returns the exit code."""
        self.signals.install()  # the domain check already makes a participant
        code, status, message = EXIT_OK, 'completed', ''
        group = self.sup.group
        try:
            self.setup.isolate()
            self.start_view()
            try:
                self.sup.check_signals()
                self.graph.init_ros()
                self.setup.launch()
                # a stop from now on ends within its grace, which grows with the load
                self.signals.watchdog.bound = self.sup.stop_bound()
                self.sup.check_signals()
                self.graph.wait_ready(
                    self.between, self.setup.domain_id, [c.name for c in group], self.sup.restart
                )
                self.run_loop()
                if self.plan.mode == 'realtime':
                    self.graph.drain()
            except StopRun as stop:
                code, status, message = stop.code, stop.status, stop.message
                self.say(('error: ' if code != EXIT_INTERRUPTED else '') + message)
            finally:
                self.t_end = time.monotonic()
                try:
                    self.sup.stop_children()
                finally:
                    self.graph.shutdown_ros()
        finally:
            if self.view is not None:
                self.view.close()
            self.signals.restore()
        if self.sup.leftovers and code == EXIT_OK:
            code, status = EXIT_CHILD_DIED, 'leftover_processes'
        if code == EXIT_OK and self.plan.mode == 'lockstep' and self.acc.dropped:
            code, status = EXIT_LOST_SAMPLES, 'lost_samples'
            self.say(
                f'error: {self.acc.dropped} /swarm/state samples were lost; the trajectory '
                'has gaps (a starved or paused bring-up: rerun on a quieter machine)'
            )
        if status != 'not_ready' and self.t_start is not None:
            write_outputs(
                plan=self.plan,
                cfg=self.cfg,
                acc=self.acc,
                fields=self.run_fields(status),
                judged=self.flight.judged if self.flight.prediction is not None else None,
                say=self.say,
            )
        return code

    def run_fields(self, status: str) -> dict[str, Any]:
        """The run's own fields of summary.json (once :attr:`t_start` is set)."""
        last, group, stops = self.acc.last, self.sup.group, self.sup.stop_how
        hows = list(stops.values())
        run_s = self.t_end - self.t_start
        fields: dict[str, Any] = {
            'status': status,
            'mode': self.plan.mode,
            'domain_id': self.setup.domain_id,
            'run_id': f'{self.run_id:x}',
            'wall_time': round(run_s, 3),
            **{
                k: int(getattr(last, k)) if last is not None else 0
                for k in ('missed_deadlines', 'stale_inputs', 'rejected_inputs')
            },
            'respawns': sum(c.respawns for c in group),
            'respawned': {c.name: c.respawns for c in group if c.respawns},
            'restarted_unseen': {c.name: c.unseen_restarts for c in group if c.unseen_restarts},
            'messages': self.acc.messages(),
            'timing': {
                'ready': round(self.t_start - self.setup.t_launch, 3),
                # the bring-up's own start to graph ready (preparation, isolation included)
                'startup': round(self.t_start - self.t_begin, 3),
                'run': round(run_s, 3),
                'shutdown': round(self.sup.stop_seconds, 3),
                'rate': round(len(self.acc.samples) / run_s, 1) if run_s > 0 else None,
            },
            'stopped_by': stops,
            'stop_signals': {how: hows.count(how) for how in sorted(set(hows))},
        }
        if self.plan.record:
            fields['recording'] = recording_fields(self.plan.out / 'bag')
            if self.sup.recorder_lost:
                lost = list(self.sup.recorder_lost.values())[-1]
                fields['recording']['recorder_died'] = describe_rc(lost)
        return fields
