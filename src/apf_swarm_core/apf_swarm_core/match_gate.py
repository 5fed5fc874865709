"""Lockstep: a publication waits until its writer has matched the readers it must reach
(:class:`MatchGate`).

Discovery is not symmetric: a reader (the plant's; the recorder's, which subscribes once it
sees a publisher) matches a writer as soon as it knows of it, but the writer sends a reliable
volatile sample only to the readers *it* has matched when the sample is written. A first
message sent in between is lost to that reader, and in lockstep nothing sends it again.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ['MatchGate']

#: a publication to run once its readers are matched
Publication = Callable[[], None]


class MatchGate:
    """Which publication goes out, given the writer's own matched count: ``first`` readers
    for the first one (the plant's and the recorder's), ``need`` for every later one (the
    plant's alone: a recorder that stops must not stop the run). One that cannot go out yet
    is held, the newest replacing an older one, until :meth:`retry` finds the readers.

    The node passes its publisher's matched count to :meth:`offer` and :meth:`retry`, runs
    the publication they return, and retries on a timer while :attr:`holding`.
    """

    def __init__(self, need: int = 1, first: int | None = None) -> None:
        self.need = int(need)
        self._want = self.need if first is None else int(first)
        self._held: Publication | None = None

    @property
    def holding(self) -> bool:
        """Whether a publication waits for its readers."""
        return self._held is not None

    def offer(self, action: Publication, matched: int) -> Publication | None:
        """``action`` to run now when ``matched`` readers suffice, else None (it is held, in
        place of one held before)."""
        self._held = action
        return self.retry(matched)

    def retry(self, matched: int) -> Publication | None:
        """The held publication to run now that ``matched`` readers suffice, or None."""
        if self._held is None or matched < self._want:
            return None
        action, self._held = self._held, None
        self._want = self.need
        return action
