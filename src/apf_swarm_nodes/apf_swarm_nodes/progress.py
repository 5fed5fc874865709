"""Progress of the long commands on stderr, through tqdm: a bar redrawn in place on a
terminal; in a pipe or in CI (stderr not a terminal) a plain line every
:data:`PIPE_INTERVAL` seconds and one at the end, never a carriage return."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import Any, TextIO, TypeVar

__all__ = ['PIPE_INTERVAL', 'Progress', 'progress_iter']

T = TypeVar('T')

#: seconds between two progress lines when stderr is not a terminal
PIPE_INTERVAL = 10.0


class _Lines:
    """A stream that turns tqdm's in-place redraws (``\\r`` + line) into whole lines."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        text = text.replace('\r', '').strip()
        if text:
            self.stream.write(text + '\n')
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


def _bar(label: str, total: int | None, unit: str, stream: TextIO | None) -> Any:
    from tqdm import tqdm

    out = stream if stream is not None else sys.stderr
    tty = bool(getattr(out, 'isatty', lambda: False)())
    return tqdm(
        total=total,
        desc=label,
        unit=' ' + unit,
        file=out if tty else _Lines(out),
        mininterval=0.1 if tty else PIPE_INTERVAL,
        dynamic_ncols=tty,
        ncols=None if tty else 100,
        ascii=not tty,
        leave=True,
    )


class Progress:
    """Callable ``progress(done, total)`` (the core's progress interface) that shows a bar
    with percentage, rate and ETA; closed when ``done`` reaches ``total``."""

    def __init__(self, label: str, stream: TextIO | None = None, unit: str = 'steps') -> None:
        self.label, self.unit, self.stream = label, unit, stream
        self._bar: Any = None

    def __call__(self, done: int, total: int) -> None:
        if self._bar is None or self._bar.total != total:
            self.close()
            self._bar = _bar(self.label, total, self.unit, self.stream)
        self._bar.update(done - self._bar.n)
        if done >= total:
            self.close()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def progress_iter(
    items: Iterable[T],
    label: str,
    *,
    total: int | None = None,
    unit: str = 'messages',
    stream: TextIO | None = None,
    quiet: bool = False,
) -> Iterator[T]:
    """``items`` with a progress bar (``total`` known: percentage and ETA)."""
    if quiet:
        yield from items
        return
    bar = _bar(label, total, unit, stream)
    try:
        for item in items:
            yield item
            bar.update(1)
    finally:
        bar.close()
