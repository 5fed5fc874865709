"""The node processes while the run lasts and at its end: SIGINT / SIGTERM to the bring-up
(:class:`Signals`), a child's death (respawned, or the run stopped, by the rules of
:meth:`Supervisor.supervise`), and every child stopped, the recorder last."""

from __future__ import annotations

import contextlib
import signal
import time
from collections.abc import Callable
from typing import Any

from ..lifetime import describe_rc
from ..stop_watchdog import StopWatchdog
from .commands import Plan
from .graph import RECORDER_STOP_SEQUENCE
from .processes import (
    EXIT_CHILD_DIED,
    EXIT_INTERRUPTED,
    Child,
    ProcessGroup,
    StopRun,
)

__all__ = ['Signals', 'Supervisor']


class Signals:
    """SIGINT / SIGTERM recorded in :attr:`received` (the loops poll it), restored on exit;
    and the stop's bound: :attr:`watchdog` ends the process with ``EXIT_INTERRUPTED``
    ``bound`` s after the first signal or :meth:`arm` (a main thread blocked in DDS never
    runs a handler); the bring-up sets it from :meth:`Supervisor.stop_bound`."""

    #: the bound [s] until the bring-up knows its processes
    BOUND = 60.0

    def __init__(self, bound: float = BOUND) -> None:
        self.received: list[int] = []
        self._old: dict[int, Any] = {}
        self.watchdog = StopWatchdog(bound, who='bring-up', code=EXIT_INTERRUPTED)

    def _handler(self, signum: int, frame: Any) -> None:
        self.received.append(signum)

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(ValueError):  # not the main thread: nothing to install
                self._old[sig] = signal.signal(sig, self._handler)
        if self._old:
            self.watchdog.install()

    def arm(self) -> None:
        """Start the bound now, signal or not: stopping must not hang either."""
        self.watchdog.arm()

    def restore(self) -> None:
        self.watchdog.close()
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()


#: seconds of a stop's bound beyond the children's stop grace (shared-memory cleanup, the
#: bring-up's own DDS shutdown, a loaded machine)
STOP_MARGIN = 10.0


def _is_tracker(child: Child) -> bool:
    """Trackers are stopped first: none commands into a plant that is gone."""
    return 'tracker' in child.name


def _not_tracker(child: Child) -> bool:
    """The plant and the target, stopped after the trackers."""
    return not _is_tracker(child)


class Supervisor:
    """The run's node processes (:attr:`group`) and recorder (:attr:`rec_group`): deaths
    reported and respawned or the run stopped, signals turned into a stop, and the stop."""

    def __init__(self, plan: Plan, signals: Signals, say: Callable[[str], None]) -> None:
        self.plan, self.signals, self.say = plan, signals, say
        self.bag = plan.out / 'bag'
        self.group = ProcessGroup()
        #: the recorder: started first, stopped last, given time to close the bag
        self.rec_group = ProcessGroup(RECORDER_STOP_SEQUENCE)
        #: a recorder that died while the run went on: its exit code
        self.recorder_lost: dict[str, int] = {}
        #: how each process was stopped, how long the stop took [s], who outlived it
        self.stop_how: dict[str, str] = {}
        self.stop_seconds = 0.0
        self.leftovers: list[tuple[str, int]] = []

    def check_signals(self) -> None:
        if self.signals.received:
            name = signal.Signals(self.signals.received[0]).name
            raise StopRun(EXIT_INTERRUPTED, 'interrupted', f'interrupted by {name}')

    def supervise(self) -> None:
        """A dead recorder stops the run (or not: ``--on-recorder-death``); a dead node is
        respawned (``--respawn``, at most ``--max-respawns`` times, never the plant) or stops
        the run."""
        for child, rc in self.rec_group.poll():
            if child.name in self.recorder_lost:
                continue
            self.say(child.death_report(rc))
            self.recorder_lost[child.name] = rc
            died = f'{child.name} died ({describe_rc(rc)})'
            reindex = f'`apf-swarm bag reindex {self.bag}` recovers what it flushed'
            if self.plan.on_recorder_death == 'continue':
                self.say(
                    f'{died}; the run continues without recording (--on-recorder-death '
                    f'continue); {reindex}'
                )
                continue
            raise StopRun(
                EXIT_CHILD_DIED,
                'child_died',
                f'{died}; stopping the run (a restarted recorder could not continue the bag; '
                f'{reindex}; --on-recorder-death continue keeps the swarm flying)',
            )
        most = self.plan.max_respawns
        for child, rc in self.group.poll():
            self.say(child.death_report(rc))
            died = f'{child.name} died ({describe_rc(rc)})'
            why_not = self.not_respawnable(child.name)
            if not self.plan.respawn:
                why = f'{died}; stopping the run'
            elif why_not:
                why = f'{died}; stopping the run: {why_not}'
            elif child.respawns >= most:
                why = (
                    f'{died} after {child.respawns} respawns (--max-respawns {most}); '
                    'stopping the run'
                )
            else:
                child.start()
                self.say(
                    f'respawned {child.name} (pid {child.pid}, respawn {child.respawns} of at '
                    f'most {most})'
                )
                continue
            raise StopRun(EXIT_CHILD_DIED, 'child_died', why)

    def restart(self, names: list[str], why: str) -> None:
        """Stop and start again the named node processes, before the run begins
        (:class:`~.graph.UnseenRestart`)."""
        chosen = set(names)
        how = self.group.stop_all(select=lambda c: c.name in chosen)
        for child in self.group:
            if child.name in chosen:
                child.start()
                child.unseen_restarts += 1
                self.say(
                    f'restarted {child.name} (pid {child.pid}, after {how.get(child.name)}): {why}'
                )

    def not_respawnable(self, name: str) -> str:
        """Why a dead node must not be restarted ('' when it may be)."""
        if name == 'plant':
            return (
                'the plant holds the state of every UAV; a restarted plant would start '
                'the world over, so it is never respawned'
            )
        if name == 'target' and self.plan.mode == 'realtime':
            return (
                'a restarted realtime target would fly its trajectory again from t = 0; '
                "only lockstep targets (driven by the plant's requests) are respawned"
            )
        return ''

    def stages(self) -> list[tuple[ProcessGroup, Callable[[Child], bool] | None]]:
        """The stop's order: the trackers, then the plant and the target, then the recorder
        (it takes what is still queued and closes the bag); (group, select)."""
        return [(self.group, _is_tracker), (self.group, _not_tracker), (self.rec_group, None)]

    def stop_bound(self) -> float:
        """The bound of the whole stop: each stage at its longest
        (:meth:`ProcessGroup.stop_grace`, which grows with the load), and :data:`STOP_MARGIN`."""
        return sum(g.stop_grace(select=select) for g, select in self.stages()) + STOP_MARGIN

    def stop_children(self) -> None:
        """Stop every child in :meth:`stages`, report how, remove stale shared memory."""
        t0 = time.monotonic()
        self.signals.arm()  # stopping has a bound too
        self.stop_how = {}
        for g, select in self.stages():
            self.stop_how.update(
                g.stop_all(hurry=lambda: len(self.signals.received), select=select)
            )
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
        # the shared memory of participants that did not leave DDS cleanly (a killed node)
        from ..dds.shm import remove_stale

        removed = remove_stale()
        if removed:
            self.say(f'removed {removed} stale Fast DDS shared-memory files (/dev/shm)')
