"""``apf-swarm bag export``: one topic's messages as CSV rows of flattened fields."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from .errors import BagError
from .info import open_bag
from .read import messages
from .types import one_line

__all__ = ['export_csv', 'flatten']


def flatten(msg: Any, prefix: str = '') -> dict[str, Any]:
    """Dotted field names and scalar values of a (rosbags-deserialized) message.

    Nested messages become ``a.b``; arrays and sequences ``a.0``, ``a.1.x``...; bytes are hex.
    """
    out: dict[str, Any] = {}

    def add(value: Any, name: str) -> None:
        if dataclasses.is_dataclass(value):
            for f in dataclasses.fields(value):
                if not f.name.startswith('__'):  # rosbags' __msgtype__
                    add(getattr(value, f.name), f'{name}.{f.name}' if name else f.name)
        elif isinstance(value, np.ndarray):
            for i, v in enumerate(value.ravel().tolist()):
                out[f'{name}.{i}'] = v
        elif isinstance(value, (list, tuple)):
            for i, v in enumerate(value):
                add(v, f'{name}.{i}')
        elif isinstance(value, (bytes, bytearray)):
            out[name] = bytes(value).hex()
        else:
            out[name] = value

    add(msg, prefix)
    return out


def export_csv(path: Path | str, topic: str, out: TextIO, *, quiet: bool = True) -> int:
    """Flattened fields of every message of ``topic`` as CSV into ``out``; returns the rows.

    Columns: ``timestamp_ns`` (the bag's receive time), then the fields in first-seen order
    (a variable-length array adds columns as it grows; shorter rows leave them empty).
    ``quiet=False``: a progress bar on stderr.
    """
    from ..progress import progress_iter

    info = open_bag(path)
    t = info.topic(topic)
    rows: list[dict[str, Any]] = []
    columns: dict[str, None] = {'timestamp_ns': None}
    found = messages(info, [topic], topic)
    for reader, conn, ts, raw in progress_iter(found, topic, total=t.count, quiet=quiet):
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as exc:
            raise BagError(
                f"{topic}: cannot decode type {t.type} ({one_line(exc)}); the bag's "
                'definition of it is missing or wrong'
            ) from None
        rows.append({'timestamp_ns': ts, **flatten(msg)})
        columns.update(dict.fromkeys(rows[-1]))
    w = csv.DictWriter(out, fieldnames=list(columns), restval='', lineterminator='\n')
    w.writeheader()
    w.writerows(rows)
    return len(rows)
