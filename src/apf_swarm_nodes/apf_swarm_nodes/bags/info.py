"""What ``apf-swarm bag info`` prints, from metadata.yaml and the MCAP summaries (never
every message), and the checks that name a broken bag."""

from __future__ import annotations

import contextlib
import json
import time
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .errors import BagError
from .types import CUSTOM_RECORDER, FILE_RE, one_line

__all__ = [
    'BagInfo',
    'FileInfo',
    'TopicInfo',
    'bag_files',
    'format_info',
    'info_dict',
    'open_bag',
    'read_metadata',
    'reindex_hint',
]


@dataclass
class TopicInfo:
    """One topic of a bag."""

    name: str
    type: str
    count: int
    serialization_format: str = 'cdr'
    offered_qos: list[dict[str, Any]] = field(default_factory=list)
    type_hash: str = ''


@dataclass
class FileInfo:
    """One MCAP file of a bag, from its summary."""

    path: Path
    size: int
    count: int
    start_ns: int
    end_ns: int
    chunks: int
    compression: str


@dataclass
class BagInfo:
    """What ``apf-swarm bag info`` shows."""

    path: Path
    storage: str
    version: int
    files: list[FileInfo]
    topics: list[TopicInfo]
    start_ns: int
    end_ns: int
    count: int
    size: int
    custom_data: dict[str, str]
    ros_distro: str = ''

    @property
    def duration(self) -> float:
        return max(0, self.end_ns - self.start_ns) / 1e9

    def topic(self, name: str) -> TopicInfo:
        for t in self.topics:
            if t.name == name:
                return t
        known = ', '.join(t.name for t in self.topics) or 'none'
        raise BagError(
            f'topic {name} is not in {self.path} (its topics: {known}); see `apf-swarm bag info`'
        )


def bag_files(path: Path) -> list[Path]:
    """The MCAP files of a bag directory, in split order."""

    def key(p: Path) -> tuple[str, int]:
        m = FILE_RE.match(p.name)
        return (m.group('stem'), int(m.group('index') or -1)) if m else (p.name, -1)

    return sorted((p for p in path.glob('*.mcap') if p.is_file()), key=key)


def reindex_hint(path: Path) -> str:
    return f'run `apf-swarm bag reindex {path}` to rebuild it from the MCAP files'


def _check_bag_dir(path: Path) -> Path:
    if not path.exists():
        raise BagError(
            f'{path}: no such file or directory; pass a bag directory (one with metadata.yaml)'
        )
    if path.is_file():
        if path.suffix == '.mcap' and (path.parent / 'metadata.yaml').is_file():
            return path.parent
        raise BagError(
            f'{path} is a file, not a bag; pass the bag directory (the one with '
            'metadata.yaml and the .mcap files)'
        )
    meta = path / 'metadata.yaml'
    if not meta.is_file():
        if bag_files(path):
            raise BagError(
                f'{path}: metadata.yaml is missing (the recorder did not close the '
                f'bag?); {reindex_hint(path)}'
            )
        raise BagError(f'{path} is not a bag: no metadata.yaml and no .mcap file in it')
    return path


def read_metadata(path: Path) -> dict[str, Any]:
    meta = path / 'metadata.yaml'
    try:
        doc = yaml.safe_load(meta.read_text())
        info = doc['rosbag2_bagfile_information']
        if not isinstance(info, dict) or 'relative_file_paths' not in info:
            raise KeyError('relative_file_paths')
    except (yaml.YAMLError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise BagError(
            f'{meta} is not rosbag2 metadata ({one_line(exc)}); {reindex_hint(path)}'
        ) from None
    return info


def _mcap_summary(file: Path) -> Any:
    """The summary section of an MCAP file; BagError when it is missing or unreadable."""
    from mcap.reader import make_reader

    bag = file.parent
    try:
        with open(file, 'rb') as f:
            summary = make_reader(f).get_summary()
    except Exception as exc:  # mcap raises McapError, EndOfFile, struct.error, ValueError...
        raise BagError(
            f'{file}: truncated or corrupt MCAP file ({one_line(exc)}); '
            f'{reindex_hint(bag)} (it keeps every complete chunk)'
        ) from None
    if summary is None or summary.statistics is None:
        raise BagError(
            f'{file}: the MCAP file has no summary section (not closed?); {reindex_hint(bag)}'
        )
    return summary


def open_bag(path: Path | str) -> BagInfo:
    """Validate a bag and read what ``info`` shows from metadata.yaml and the MCAP summaries.

    Only the summary section of each MCAP file is read (footer, statistics, chunk indexes),
    so the time does not grow with the number of messages beyond the chunk index.
    """
    path = _check_bag_dir(Path(path))
    meta = read_metadata(path)
    storage = str(meta.get('storage_identifier', ''))
    if storage != 'mcap':
        raise BagError(
            f'{path}: storage {storage!r} is not supported here (only mcap); convert '
            'it with `rosbags-convert` or `ros2 bag convert`'
        )
    files: list[FileInfo] = []
    counts: dict[str, int] = defaultdict(int)
    for rel in meta.get('relative_file_paths') or []:
        file = path / rel
        if not file.is_file():
            raise BagError(
                f'{path}: {rel} is listed in metadata.yaml but missing; {reindex_hint(path)}'
            )
        s = _mcap_summary(file)
        st = s.statistics
        compressions = {ci.compression for ci in s.chunk_indexes} - {''}
        files.append(
            FileInfo(
                file,
                file.stat().st_size,
                int(st.message_count),
                int(st.message_start_time),
                int(st.message_end_time),
                int(st.chunk_count),
                ','.join(sorted(compressions)) or 'none',
            )
        )
        for cid, n in st.channel_message_counts.items():
            ch = s.channels.get(cid)
            if ch is not None:
                counts[ch.topic] += int(n)
    topics = []
    for entry in meta.get('topics_with_message_count') or []:
        tm = entry.get('topic_metadata', {})
        qos = tm.get('offered_qos_profiles') or []
        if isinstance(qos, str):  # version <= 8 stores a YAML string
            qos = yaml.safe_load(qos) or []
        name = tm.get('name', '')
        topics.append(
            TopicInfo(
                name,
                tm.get('type', ''),
                counts.get(name, 0),
                tm.get('serialization_format', 'cdr'),
                list(qos),
                tm.get('type_description_hash', ''),
            )
        )
    used = [f for f in files if f.count]
    start = min((f.start_ns for f in used), default=0)
    end = max((f.end_ns for f in used), default=0)
    custom = meta.get('custom_data') or {}
    return BagInfo(
        path,
        storage,
        int(meta.get('version', 0)),
        files,
        topics,
        start,
        end,
        sum(f.count for f in files),
        sum(f.size for f in files),
        {str(k): str(v) for k, v in custom.items()},
        str(meta.get('ros_distro', '')),
    )


def _human_size(n: float) -> str:
    unit = 'B'
    for bigger in ('KiB', 'MiB', 'GiB'):
        if n < 1024:
            break
        n, unit = n / 1024, bigger
    return f'{n:.1f} {unit}' if unit != 'B' else f'{int(n)} B'


def _stamp(ns: int) -> str:
    return (
        time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime(ns // 1_000_000_000))
        + f'.{ns % 1_000_000_000:09d} UTC ({ns // 1_000_000_000}.{ns % 1_000_000_000:09d})'
    )


def _qos_short(qos: Sequence[Mapping[str, Any]]) -> str:
    if not qos:
        return '-'
    out = []
    for q in qos:
        depth = q.get('depth', 0)
        hist = q.get('history', 'unknown')
        h = f'{hist} {depth}' if hist not in ('unknown', 'system_default') or depth else hist
        out.append(f'{q.get("reliability", "?")}/{q.get("durability", "?")}/{h}')
    uniq = sorted(set(out))
    return ', '.join(uniq) + (f' ({len(out)} publishers)' if len(out) > 1 else '')


def info_dict(info: BagInfo) -> dict[str, Any]:
    """``info`` as a JSON-able mapping (``apf-swarm bag info --json``)."""
    dur = info.duration
    return {
        'path': str(info.path),
        'storage': info.storage,
        'version': info.version,
        'files': [
            {
                'path': f.path.name,
                'size': f.size,
                'messages': f.count,
                'chunks': f.chunks,
                'compression': f.compression,
            }
            for f in info.files
        ],
        'size': info.size,
        'duration': dur,
        'start_ns': info.start_ns,
        'end_ns': info.end_ns,
        'messages': info.count,
        'topics': {
            t.name: {
                'type': t.type,
                'count': t.count,
                'frequency': (t.count / dur) if dur > 0 else None,
                'serialization_format': t.serialization_format,
                'offered_qos_profiles': t.offered_qos,
                'type_description_hash': t.type_hash,
            }
            for t in info.topics
        },
        'custom_data': info.custom_data,
    }


def format_info(info: BagInfo) -> str:
    """The text of ``apf-swarm bag info``."""
    dur = info.duration
    comp = sorted({f.compression for f in info.files})
    lines = [
        f'Bag:          {info.path}',
        (
            f'Storage:      {info.storage} (rosbag2 metadata version {info.version}), '
            f'chunk compression: {", ".join(comp) or "none"}'
        ),
        'Files:        '
        + ', '.join(
            f'{f.path.name} ({_human_size(f.size)}, {f.count} messages, {f.chunks} chunks)'
            for f in info.files
        ),
        f'Size:         {_human_size(info.size)} ({info.size} bytes)',
        f'Duration:     {dur:.3f} s',
        f'Start:        {_stamp(info.start_ns) if info.count else "-"}',
        f'End:          {_stamp(info.end_ns) if info.count else "-"}',
        f'Messages:     {info.count}',
        f'Topics:       {len(info.topics)}',
    ]
    w = max((len(t.name) for t in info.topics), default=5)
    wt = max((len(t.type) for t in info.topics), default=4)
    lines.append(
        f'  {"topic":{w}s}  {"type":{wt}s}  {"count":>9s}  {"freq [Hz]":>9s}  QoS '
        '(reliability/durability/history depth)'
    )
    for t in info.topics:
        freq = f'{t.count / dur:9.1f}' if dur > 0 else f'{"-":>9s}'
        lines.append(
            f'  {t.name:{w}s}  {t.type:{wt}s}  {t.count:9d}  {freq}  {_qos_short(t.offered_qos)}'
        )
    with contextlib.suppress(ValueError):
        r = json.loads(info.custom_data.get(CUSTOM_RECORDER) or 'null') or {}
        if r:
            lines.append(
                f'Recorder:     received {r.get("received")}, written '
                f'{r.get("written")}, dropped {r.get("dropped")}'
            )
    return '\n'.join(lines)
