"""A bound on how long a process takes to end once it is told to stop, whatever its main
thread is doing (a main thread blocked inside a DDS call never runs a Python signal
handler).

The C-level handler writes each signal's number to a pipe (``signal.set_wakeup_fd``); a
thread reading it gives the process :attr:`~StopWatchdog.bound` seconds from the first
SIGINT / SIGTERM (or from :meth:`~StopWatchdog.arm`, a stop without a signal),
:attr:`~StopWatchdog.hard_after` seconds from a second one, then writes one line saying why
and ends the process with ``os._exit``. The bring-up, every node process and the recorder
install one (docs/RELIABILITY.md, "Shared memory and orphans"). The wakeup pipe only
receives signals that have a Python handler: install the handlers first.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import threading
import time

__all__ = ['HARD_STOP_AFTER', 'NODE_STOP_BOUND', 'StopWatchdog']

#: seconds from a second SIGINT / SIGTERM to the hard exit
HARD_STOP_AFTER = 5.0
#: seconds a node process has from its stop (signal or end) to its exit: leaving DDS takes
#: well under a second of CPU; the bring-up's own escalation (SIGTERM, then SIGKILL) comes
#: sooner, so this bounds nodes started by hand and a stop that hangs with nobody escalating
NODE_STOP_BOUND = 20.0
#: exit code of the hard exit (as for an interrupted process)
EXIT_HARD = 130

#: the byte :meth:`StopWatchdog.arm` writes (no signal has this number)
_ARM = 0xFF
_STOPS = (signal.SIGINT, signal.SIGTERM)


class StopWatchdog:
    """The bound on a stop, in a daemon thread; see the module docstring.

    ``who`` names the process in the line of the hard exit; ``code`` is its exit code.
    :attr:`bound` may be changed while the watchdog runs (a bring-up sizes it once it knows
    how many processes it will have to stop); it applies from the next arming.
    """

    def __init__(
        self,
        bound: float,
        *,
        who: str,
        hard_after: float = HARD_STOP_AFTER,
        code: int = EXIT_HARD,
    ) -> None:
        self.bound, self.who, self.hard_after, self.code = bound, who, hard_after, code
        self._done = threading.Event()
        self._pipe: tuple[int, int] | None = None
        self._old_wakeup = -1
        #: monotonic time of the hard exit once armed (for tests and messages)
        self.deadline: float | None = None
        self._why = ''

    def install(self) -> StopWatchdog:
        """Take the process's wakeup fd and start the thread (main thread only; elsewhere, or
        where the wakeup fd cannot be set, nothing happens)."""
        if self._pipe is not None:
            return self
        r, w = os.pipe()
        os.set_blocking(w, False)
        try:
            self._old_wakeup = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
        except ValueError:  # not the main thread
            os.close(r)
            os.close(w)
            return self
        self._pipe = (r, w)
        self._done.clear()
        threading.Thread(target=self._watch, args=(r,), name='stop-watchdog', daemon=True).start()
        return self

    def arm(self) -> None:
        """Start the bound now, signal or not: the process is stopping (its end, a failed
        start, a child's death), and stopping must not hang either."""
        if self._pipe is not None:
            with contextlib.suppress(OSError):
                os.write(self._pipe[1], bytes([_ARM]))

    def close(self) -> None:
        """Stop the thread and give the wakeup fd back (the process ended its stop in time)."""
        self._done.set()
        if self._pipe is None:
            return
        with contextlib.suppress(ValueError):
            signal.set_wakeup_fd(self._old_wakeup)
        w = self._pipe[1]
        with contextlib.suppress(OSError):
            os.write(w, b'\0')  # wake the thread, which sees _done (and closes its end)
        with contextlib.suppress(OSError):
            os.close(w)
        self._pipe = None

    # --- the thread ---------------------------------------------------------------------
    def _watch(self, fd: int) -> None:
        try:
            while not self._done.is_set():
                deadline = self.deadline
                timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
                ready, _, _ = select.select([fd], [], [], timeout)
                if self._done.is_set():
                    return
                if ready:
                    data = os.read(fd, 64)
                    if not data:
                        return
                    self._take(data, time.monotonic())
                elif self.deadline is not None and time.monotonic() >= self.deadline:
                    why = f'{self.who}: still not ended {self._why} (a call blocked inside DDS?)'
                    with contextlib.suppress(OSError):
                        os.write(2, f'{why}: exiting now, outputs may be missing\n'.encode())
                    os._exit(self.code)
        except OSError:
            return
        finally:
            with contextlib.suppress(OSError):
                os.close(fd)

    def _take(self, data: bytes, now: float) -> None:
        """What the bytes read from the pipe do to the deadline."""
        for b in data:
            if b in _STOPS:
                name = signal.Signals(b).name
                if self.deadline is None:
                    self.deadline = now + self.bound
                    self._why = f'{self.bound:g} s after {name}'
                elif now + self.hard_after < self.deadline:
                    self.deadline = now + self.hard_after
                    self._why = f'{self.hard_after:g} s after a second stop signal ({name})'
            elif b == _ARM and self.deadline is None:
                self.deadline = now + self.bound
                self._why = f'{self.bound:g} s after its stop began'
