"""A minimal progress line on stderr: redrawn in place on a terminal, every 10 % otherwise."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ['Progress']


class Progress:
    """Callable ``progress(done, total)`` that reports percentage, rate and ETA."""

    def __init__(self, label: str, stream: TextIO | None = None, unit: str = 'steps') -> None:
        self.label, self.unit = label, unit
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, 'isatty', lambda: False)())
        self.t0 = time.monotonic()
        self._last_decile = -1

    def __call__(self, done: int, total: int) -> None:
        frac = done / total if total else 1.0
        elapsed = time.monotonic() - self.t0
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = (total - done) / rate if rate > 0 else 0.0
        line = (
            f'{self.label}: {100 * frac:5.1f}% ({done}/{total} {self.unit}, '
            f'{rate:,.0f} {self.unit}/s, ETA {eta:4.1f} s)'
        )
        if self.tty:
            self.stream.write('\r' + line + ('\n' if done >= total else ''))
            self.stream.flush()
        else:
            decile = int(frac * 10)
            if decile != self._last_decile:
                self._last_decile = decile
                self.stream.write(line + '\n')
                self.stream.flush()
