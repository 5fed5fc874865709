"""Bags of the swarm: rosbag2 directories (metadata.yaml version 9 + MCAP storage), no ROS graph.

A bag written here is an ordinary rosbag2 bag: rosbags' ``AnyReader``, the ``mcap`` readers,
Foxglove and ``ros2 bag`` on a full ROS install open it. Layout of a bag directory ``BAG/``::

    BAG/metadata.yaml        rosbag2 metadata, version 9 (topics, types, offered QoS, counts,
                             files, custom_data: apf_swarm.recorder / .config / .mode)
    BAG/BAG_0.mcap           MCAP storage: one schema (ros2msg, full definition) per type, one
    BAG/BAG_1.mcap ...       channel per topic (offered_qos_profiles in its metadata), chunked
                             messages (zstd-compressed chunks with ``compress``); more files
                             only when split by size or duration

What is here (all of it without rclpy, except :func:`swarm_state_accumulator`, which reuses
the bring-up's deserialization so that ``bag metrics`` equals the live ``summary.json``):

* :class:`BagWriter` -- raw CDR bytes into a bag, on rosbags' ``Writer`` and its MCAP
  storage; chunks are flushed to the file on :meth:`BagWriter.flush` so that a killed writer
  leaves every flushed chunk recoverable; optional zstd chunk compression and splitting;
* :func:`type_definition` -- the full ``ros2msg`` definition and RIHS01 hash of a type (the
  rosbags Jazzy type store plus the ``.msg`` files of the ament index, custom types included);
* :func:`open_bag` / :func:`format_info` -- what ``apf-swarm bag info`` prints, from
  metadata.yaml and the MCAP summaries (never every message);
* :func:`iter_raw`, :func:`bag_metrics`, :func:`bag_trajectory`, :func:`export_csv`,
  :func:`reindex` -- the other ``apf-swarm bag`` commands.

Every expected problem (no such path, not a bag, missing metadata.yaml, truncated or corrupt
MCAP, unknown topic or type) raises :class:`~apf_swarm_nodes.errors.CliError` with one line that
names it and says what to do.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import os
import re
import shutil
import time
from collections import defaultdict
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache, lru_cache
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import yaml

from .errors import CliError

__all__ = [
    'BAG_VERSION',
    'CUSTOM_CONFIG',
    'CUSTOM_MODE',
    'CUSTOM_RECORDER',
    'BagInfo',
    'BagWriter',
    'FileInfo',
    'TopicInfo',
    'bag_config',
    'bag_files',
    'bag_metrics',
    'bag_trajectory',
    'export_csv',
    'flatten',
    'format_info',
    'info_dict',
    'iter_raw',
    'open_bag',
    'reindex',
    'swarm_state_accumulator',
    'type_definition',
    'typestore',
]

BAG_VERSION = 9
#: custom_data keys (metadata.yaml) and the MCAP metadata record the recorder writes first
CUSTOM_RECORDER = 'apf_swarm.recorder'  # JSON: received / written / dropped counts
CUSTOM_CONFIG = 'apf_swarm.config'  # the run's ROS 2 parameter file (YAML text)
CUSTOM_MODE = 'apf_swarm.mode'  # lockstep | realtime
MCAP_METADATA_NAME = 'apf_swarm'
DEFAULT_CHUNK_SIZE = 1 << 20
SWARM_STATE_TOPIC = '/swarm/state'
SWARM_STATE_TYPE = 'apf_swarm_msgs/msg/SwarmState'
_FILE_RE = re.compile(r'^(?P<stem>.*?)(?:_(?P<index>\d+))?\.mcap$')


# --------------------------------------------------------------------------------------------
# types and QoS
# --------------------------------------------------------------------------------------------


def _msg_search_dirs() -> list[Path]:
    """``share/`` directories of the ament index, then the repository's ``src/`` (a fresh
    checkout before ``make``)."""
    dirs = []
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / 'share')
    dirs.append(Path(__file__).resolve().parents[2])  # src/ of the repository
    return dirs


def _find_msg_file(msgtype: str) -> Path | None:
    pkg, _, name = msgtype.partition('/msg/')
    if not name:
        return None
    for d in _msg_search_dirs():
        for cand in (d / pkg / 'msg' / f'{name}.msg', d / pkg / pkg / 'msg' / f'{name}.msg'):
            if cand.is_file():
                return cand
    return None


@lru_cache(maxsize=1)
def typestore() -> Any:
    """The rosbags Jazzy type store with apf_swarm_msgs registered from their ``.msg`` files."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for name in ('ForceCommand', 'SwarmOdometry', 'SwarmState'):
        path = _find_msg_file(f'apf_swarm_msgs/msg/{name}')
        if path is not None:
            types.update(get_types_from_msg(path.read_text(), f'apf_swarm_msgs/msg/{name}'))
    store.register(types)
    return store


def _register_from_index(store: Any, msgtype: str, seen: set[str] | None = None) -> bool:
    """Register ``msgtype`` (and its dependencies) from ``.msg`` files of the ament index."""
    from rosbags.typesys import get_types_from_msg

    seen = set() if seen is None else seen
    if msgtype in store.fielddefs or msgtype in seen:
        return True
    seen.add(msgtype)
    path = _find_msg_file(msgtype)
    if path is None:
        return False
    types = get_types_from_msg(path.read_text(), msgtype)
    store.register(types)
    return msgtype in store.fielddefs


@cache
def type_definition(msgtype: str) -> tuple[str, str]:
    """The full ``ros2msg`` definition text (dependencies included) and the RIHS01 hash.

    Raises CliError for a type that is neither in the Jazzy type store nor in a ``.msg`` file
    of the ament index.
    """
    store = typestore()
    try:
        if msgtype not in store.fielddefs and not _register_from_index(store, msgtype):
            raise KeyError(msgtype)
        msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
        return msgdef, store.hash_rihs01(msgtype)
    except Exception as exc:  # rosbags raises TypesysError / KeyError for missing dependencies
        raise CliError(
            f'message type {msgtype} is unknown: it is not a ROS 2 Jazzy type and no '
            f'{msgtype}.msg is in the ament index ({_one_line(exc)}); build and '
            'source the package that defines it'
        ) from None


def _qos_text(qos: Sequence[Any]) -> str:
    """offered_qos_profiles as the YAML string stored in an MCAP channel (as rosbags does)."""
    from rosbags.rosbag2.metadata import dump_qos_v9

    return yaml.safe_dump(dump_qos_v9(list(qos)), default_flow_style=False).strip()


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------


def _storage_class() -> type:
    """rosbags' MCAP storage with an explicit file name, a chunk size and :meth:`flush`.

    rosbags closes a chunk at 1 MiB and writes the file only then; a recorder must be able to
    close and flush the pending chunk on a timer (SIGKILL loses only the pending chunk) and to
    name split files. Only ``__init__`` and ``write`` differ from rosbags 0.11's McapWriter
    (pinned in requirements.txt).
    """
    from collections import defaultdict as _dd
    from importlib.metadata import version as _version

    from rosbags.rosbag2.enums import CompressionMode
    from rosbags.rosbag2.storage_mcap import (
        McapWriter,
        PendingChunk,
        write_record,
        write_string,
        write_uint16,
        write_uint32,
        write_uint64,
    )

    class ChunkedMcapStorage(McapWriter):
        def __init__(
            self, file: Path, compression: Any, chunk_size: int = DEFAULT_CHUNK_SIZE
        ) -> None:
            from rosbags.rosbag2.storage_mcap import zstd

            self.path = file
            self.bio = self.path.open('xb')
            self.bio.write(b'\x89MCAP\x30\r\n')
            rec = io.BytesIO()
            write_string(rec, 'ros2')
            write_string(rec, f'rosbags-{_version("rosbags")}')
            write_record(self.bio, 0x01, rec)
            self.schemas = []
            self.channels = []
            self.chunks = []
            self.chunk = PendingChunk(2**63 - 1, 0, io.BytesIO(), _dd(list))
            if compression == CompressionMode.STORAGE:
                self.compression = 'zstd'
                self.compressor = zstd.compress
            else:
                self.compression = ''
                self.compressor = lambda x: x
            self.message_start_time = 2**63 - 1
            self.message_end_time = 0
            self.channel_stats = {}
            self.chunk_size = int(chunk_size)

        def write(self, connection: Any, timestamp: int, data: bytes | memoryview) -> None:
            self.message_start_time = min(timestamp, self.message_start_time)
            self.message_end_time = max(timestamp, self.message_end_time)
            self.channel_stats[connection.id] += 1
            chunk = self.chunk
            chunk.message_start_time = min(timestamp, chunk.message_start_time)
            chunk.message_end_time = max(timestamp, chunk.message_end_time)
            chunk.msgs[connection.id].append((timestamp, chunk.bio.tell()))
            rec = io.BytesIO()
            write_uint16(rec, connection.id)
            write_uint32(rec, 0)
            write_uint64(rec, timestamp)
            write_uint64(rec, timestamp)
            rec.write(data)
            write_record(chunk.bio, 0x05, rec)
            if chunk.bio.tell() >= self.chunk_size:
                self.close_chunk()
                self.bio.flush()

        def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
            """An MCAP Metadata record in the data section (survives a killed writer)."""
            rec = io.BytesIO()
            write_string(rec, name)
            sub = io.BytesIO()
            for k, v in data.items():
                write_string(sub, k)
                write_string(sub, v)
            write_uint32(rec, sub.tell())
            rec.write(sub.getbuffer())
            write_record(self.bio, 0x0C, rec)

        def pending_bytes(self) -> int:
            return self.chunk.bio.tell()

        def file_bytes(self) -> int:
            return self.bio.tell() + self.chunk.bio.tell()

        def flush(self, fsync: bool = False) -> None:
            """Close the pending chunk (if any) and hand the file's buffer to the OS."""
            if self.chunk.bio.tell():
                self.close_chunk()
            self.bio.flush()
            if fsync:
                os.fsync(self.bio.fileno())

    return ChunkedMcapStorage


@dataclass
class _FileStats:
    path: str
    start: int = 2**63 - 1
    end: int = 0
    count: int = 0

    def as_dict(self) -> dict[str, Any]:
        start = self.start if self.count else 0
        return {
            'path': self.path,
            'starting_time': {'nanoseconds_since_epoch': start},
            'duration': {'nanoseconds': max(0, self.end - start) if self.count else 0},
            'message_count': self.count,
        }


def build_metadata(
    *,
    files: Sequence[Mapping[str, Any]],
    topics: Sequence[Mapping[str, Any]],
    custom_data: Mapping[str, str] | None = None,
    ros_distro: str = 'rosbags',
) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` document (version 9) of a bag.

    ``files``: ``{path, starting_time, duration, message_count}`` per MCAP file (as
    :class:`_FileStats`); ``topics``: ``{name, type, serialization_format,
    offered_qos_profiles (list of v9 mappings), type_description_hash, message_count}``.
    """
    counted = [f for f in files if f['message_count']]
    start = min((f['starting_time']['nanoseconds_since_epoch'] for f in counted), default=0)
    end = max(
        (
            f['starting_time']['nanoseconds_since_epoch'] + f['duration']['nanoseconds']
            for f in counted
        ),
        default=0,
    )
    return {
        'rosbag2_bagfile_information': {
            'version': BAG_VERSION,
            'storage_identifier': 'mcap',
            'relative_file_paths': [f['path'] for f in files],
            'duration': {'nanoseconds': max(0, end - start)},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': sum(int(f['message_count']) for f in files),
            'topics_with_message_count': [
                {
                    'topic_metadata': {
                        'name': t['name'],
                        'type': t['type'],
                        'serialization_format': t.get('serialization_format', 'cdr'),
                        'offered_qos_profiles': list(t.get('offered_qos_profiles', [])),
                        'type_description_hash': t.get('type_description_hash', ''),
                    },
                    'message_count': int(t['message_count']),
                }
                for t in topics
            ],
            'compression_format': '',
            'compression_mode': '',
            'files': [dict(f) for f in files],
            'custom_data': dict(custom_data) if custom_data else None,
            'ros_distro': ros_distro,
        }
    }


def _write_metadata(path: Path, doc: Mapping[str, Any]) -> None:
    tmp = path.with_suffix('.yaml.tmp')
    tmp.write_text(yaml.safe_dump(dict(doc), sort_keys=False, default_flow_style=False))
    tmp.replace(path)


class BagWriter:
    """Raw CDR messages into a new rosbag2 bag (metadata.yaml v9, MCAP), with rosbags.

    Parameters
    ----------
    path
        The bag directory; it must not exist yet (nothing existing is ever overwritten).
    compress
        zstd-compress every chunk (MCAP chunk compression, what ``ros2 bag``'s ``zstd_fast``
        storage preset writes); readers decompress transparently.
    chunk_size
        Uncompressed bytes after which a chunk is closed and handed to the OS.
    split_size, split_duration
        Start a new file ``BAG_<k>.mcap`` when the current one reaches this many bytes / spans
        this many seconds of message time (0: never).

    Notes
    -----
    Topics are added with :meth:`add_topic` (type, full definition, RIHS01 hash, offered QoS);
    :meth:`write` takes the bytes as received; :meth:`flush` closes the pending chunk, so a
    writer killed afterwards loses nothing written before it (``apf-swarm bag reindex``
    rebuilds the summary and metadata.yaml); :meth:`close` writes the summaries and
    metadata.yaml.
    """

    def __init__(
        self,
        path: Path | str,
        *,
        compress: bool = False,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        split_size: int = 0,
        split_duration: float = 0.0,
    ) -> None:
        from rosbags.rosbag2 import Writer
        from rosbags.rosbag2.enums import CompressionMode

        self.path = Path(path)
        if self.path.exists():
            raise CliError(
                f'{self.path} exists already; a bag is never overwritten: choose a new '
                'output directory'
            )
        self.compression = CompressionMode.STORAGE if compress else CompressionMode.NONE
        self.chunk_size = max(1024, int(chunk_size))
        self.split_size = int(split_size)
        self.split_ns = int(round(split_duration * 1e9))
        # rosbags' Writer keeps the connections (definitions, hashes, QoS) and the counts; the
        # storage is ours (file names, chunk size, flush)
        self._rw = Writer(self.path, version=BAG_VERSION)
        self._storage_cls = _storage_class()
        self.custom_data: dict[str, str] = {}
        self.files: list[_FileStats] = []
        self.storage: Any = None
        self._qos: dict[int, str] = {}
        self._mcap_metadata: dict[str, str] = {}

    # --- set-up ---------------------------------------------------------------------------
    def open(self) -> BagWriter:
        self.path.mkdir(mode=0o755, parents=True)
        self._rw.storage = self._new_storage()
        return self

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, *exc: Any) -> None:
        if self.storage is not None:
            self.close()

    def _new_storage(self) -> Any:
        name = f'{self.path.name}_{len(self.files)}.mcap'
        self.files.append(_FileStats(name))
        self.storage = self._storage_cls(self.path / name, self.compression, self.chunk_size)
        self._file_start = None
        if self._mcap_metadata:
            self.storage.add_metadata(MCAP_METADATA_NAME, self._mcap_metadata)
        return self.storage

    def set_custom_data(self, key: str, value: str, *, early: bool = False) -> None:
        """A ``custom_data`` entry of metadata.yaml; ``early``: also an MCAP Metadata record
        written now (and at the start of every split file), so that ``reindex`` finds it in a
        bag whose writer was killed."""
        self.custom_data[key] = str(value)
        if early:
            self._mcap_metadata[key] = str(value)
            if self.storage is not None:
                self.storage.add_metadata(MCAP_METADATA_NAME, {key: str(value)})

    def add_topic(
        self,
        topic: str,
        msgtype: str,
        *,
        msgdef: str | None = None,
        rihs01: str | None = None,
        offered_qos: Sequence[Any] = (),
    ) -> Any:
        """Register a topic; returns the connection to pass to :meth:`write`.

        Without ``msgdef`` / ``rihs01`` they come from :func:`type_definition` (CliError for a
        type nobody knows).
        """
        if msgdef is None or rihs01 is None:
            d, h = type_definition(msgtype)
            msgdef, rihs01 = msgdef or d, rihs01 or h
        conn = self._rw.add_connection(
            topic, msgtype, msgdef=msgdef, rihs01=rihs01, offered_qos_profiles=list(offered_qos)
        )
        self._qos[conn.id] = _qos_text(offered_qos)
        return conn

    # --- data -----------------------------------------------------------------------------
    def write(self, conn: Any, timestamp: int, data: bytes | memoryview) -> None:
        """One serialized message at ``timestamp`` (ns since the epoch)."""
        if self._file_start is None:
            self._file_start = timestamp
        elif (self.split_size and self.storage.file_bytes() >= self.split_size) or (
            self.split_ns and timestamp - self._file_start >= self.split_ns
        ):
            self.split()
            self._file_start = timestamp
        self._rw.write(conn, timestamp, data)
        f = self.files[-1]
        f.count += 1
        f.start = min(f.start, timestamp)
        f.end = max(f.end, timestamp)

    def flush(self, fsync: bool = False) -> None:
        """Close the pending chunk and hand it to the OS (``fsync``: also to the disk)."""
        if self.storage is not None:
            self.storage.flush(fsync)

    def split(self) -> None:
        """Close the current file and continue in ``BAG_<k+1>.mcap`` (same topics)."""
        self._close_storage()
        self._rw.storage = self._new_storage()
        seen: set[str] = set()
        for conn in self._rw.connections:
            if conn.msgtype not in seen:
                self.storage.add_msgtype(conn)
                seen.add(conn.msgtype)
            self.storage.add_connection(conn, self._qos[conn.id])

    def _close_storage(self) -> None:
        doc = self.metadata()['rosbag2_bagfile_information']
        self.storage.close(BAG_VERSION, yaml.safe_dump(doc, sort_keys=False).strip())
        self.storage = None

    # --- the end --------------------------------------------------------------------------
    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        return {c.topic: self._rw.counts[c.id] for c in self._rw.connections}

    @property
    def written(self) -> int:
        return sum(self._rw.counts.values())

    def metadata(self) -> dict[str, Any]:
        from rosbags.rosbag2.metadata import dump_qos_v9

        topics = [
            {
                'name': c.topic,
                'type': c.msgtype,
                'serialization_format': c.ext.serialization_format,
                'offered_qos_profiles': dump_qos_v9(c.ext.offered_qos_profiles),
                'type_description_hash': c.digest,
                'message_count': self._rw.counts[c.id],
            }
            for c in self._rw.connections
        ]
        return build_metadata(
            files=[f.as_dict() for f in self.files], topics=topics, custom_data=self.custom_data
        )

    def close(self) -> None:
        """Write the MCAP summary and metadata.yaml."""
        if self.storage is None:
            return
        self._close_storage()
        self._rw.storage = None
        _write_metadata(self.path / 'metadata.yaml', self.metadata())


# --------------------------------------------------------------------------------------------
# reading: info
# --------------------------------------------------------------------------------------------


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
        raise CliError(
            f'topic {name} is not in {self.path} (its topics: {known}); see `apf-swarm bag info`'
        )


def bag_files(path: Path) -> list[Path]:
    """The MCAP files of a bag directory, in split order."""

    def key(p: Path) -> tuple[str, int]:
        m = _FILE_RE.match(p.name)
        return (m.group('stem'), int(m.group('index') or -1)) if m else (p.name, -1)

    return sorted((p for p in path.glob('*.mcap') if p.is_file()), key=key)


def _one_line(exc: BaseException) -> str:
    """``Type: message`` of an exception on one line (parsers report over several)."""
    text = ' '.join(str(exc).split())
    if len(text) > 300:
        text = text[:297] + '...'
    return f'{type(exc).__name__}: {text}' if text else type(exc).__name__


def _read_error(path: Path, exc: BaseException, what: str = 'the messages') -> CliError:
    """A failure while reading messages of an opened bag: a damaged file."""
    return CliError(
        f'{path}: cannot read {what}, the file is damaged ({_one_line(exc)}); '
        f'{_reindex_hint(path)}'
    )


def _reindex_hint(path: Path) -> str:
    return f'run `apf-swarm bag reindex {path}` to rebuild it from the MCAP files'


def _check_bag_dir(path: Path) -> Path:
    path = Path(path)
    if not path.exists():
        raise CliError(
            f'{path}: no such file or directory; pass a bag directory (one with metadata.yaml)'
        )
    if path.is_file():
        if path.suffix == '.mcap' and (path.parent / 'metadata.yaml').is_file():
            return path.parent
        raise CliError(
            f'{path} is a file, not a bag; pass the bag directory (the one with '
            'metadata.yaml and the .mcap files)'
        )
    meta = path / 'metadata.yaml'
    if not meta.is_file():
        if bag_files(path):
            raise CliError(
                f'{path}: metadata.yaml is missing (the recorder did not close the '
                f'bag?); {_reindex_hint(path)}'
            )
        raise CliError(f'{path} is not a bag: no metadata.yaml and no .mcap file in it')
    return path


def _read_metadata(path: Path) -> dict[str, Any]:
    meta = path / 'metadata.yaml'
    try:
        doc = yaml.safe_load(meta.read_text())
        info = doc['rosbag2_bagfile_information']
        if not isinstance(info, dict) or 'relative_file_paths' not in info:
            raise KeyError('relative_file_paths')
    except (yaml.YAMLError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise CliError(
            f'{meta} is not rosbag2 metadata ({_one_line(exc)}); {_reindex_hint(path)}'
        ) from None
    return info


def _mcap_summary(file: Path) -> Any:
    """The summary section of an MCAP file; CliError when it is missing or unreadable."""
    from mcap.reader import make_reader

    bag = file.parent
    try:
        with open(file, 'rb') as f:
            summary = make_reader(f).get_summary()
    except Exception as exc:  # mcap raises McapError, EndOfFile, struct.error, ValueError...
        raise CliError(
            f'{file}: truncated or corrupt MCAP file ({_one_line(exc)}); '
            f'{_reindex_hint(bag)} (it keeps every complete chunk)'
        ) from None
    if summary is None or summary.statistics is None:
        raise CliError(
            f'{file}: the MCAP file has no summary section (not closed?); {_reindex_hint(bag)}'
        )
    return summary


def open_bag(path: Path | str) -> BagInfo:
    """Validate a bag and read what ``info`` shows from metadata.yaml and the MCAP summaries.

    Only the summary section of each MCAP file is read (footer, statistics, chunk indexes),
    so the time does not grow with the number of messages beyond the chunk index.
    """
    path = _check_bag_dir(Path(path))
    meta = _read_metadata(path)
    storage = str(meta.get('storage_identifier', ''))
    if storage != 'mcap':
        raise CliError(
            f'{path}: storage {storage!r} is not supported here (only mcap); convert '
            'it with `rosbags-convert` or `ros2 bag convert`'
        )
    files: list[FileInfo] = []
    counts: dict[str, int] = defaultdict(int)
    for rel in meta.get('relative_file_paths') or []:
        file = path / rel
        if not file.is_file():
            raise CliError(
                f'{path}: {rel} is listed in metadata.yaml but missing; {_reindex_hint(path)}'
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
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if n < 1024 or unit == 'GiB':
            return f'{n:.1f} {unit}' if unit != 'B' else f'{int(n)} B'
        n /= 1024
    return f'{n:.1f} TiB'


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
    rec = info.custom_data.get(CUSTOM_RECORDER)
    if rec:
        try:
            r = json.loads(rec)
            lines.append(
                f'Recorder:     received {r.get("received")}, written '
                f'{r.get("written")}, dropped {r.get("dropped")}'
            )
        except ValueError:
            pass
    return '\n'.join(lines)


# --------------------------------------------------------------------------------------------
# reading: messages
# --------------------------------------------------------------------------------------------


def _any_reader(path: Path) -> Any:
    """An opened rosbags AnyReader (types from the bag's own definitions); opening parses
    every stored definition, so a failure here is a broken definition, not a damaged file."""
    from rosbags.highlevel import AnyReader

    reader = AnyReader([path], default_typestore=typestore())
    try:
        reader.open()
    except Exception as exc:
        raise CliError(
            f'{path}: cannot load the type definitions stored in the bag '
            f'({_one_line(exc)}); it was not written with full, valid ros2msg '
            'definitions'
        ) from None
    return reader


def iter_raw(
    path: Path | str, topics: Iterable[str] | None = None, *, info: BagInfo | None = None
) -> Iterator[tuple[str, str, int, bytes]]:
    """``(topic, type, timestamp_ns, cdr bytes)`` of every message, in time order.

    ``topics``: only these (CliError for a topic that is not in the bag).
    """
    info = info or open_bag(path)
    wanted = None
    if topics is not None:
        wanted = set(topics)
        for t in wanted:
            info.topic(t)
    try:
        with contextlib.closing(_any_reader(info.path)) as reader:
            conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
            for conn, ts, raw in reader.messages(connections=conns):
                yield conn.topic, conn.msgtype, int(ts), bytes(raw)
    except CliError:
        raise
    except Exception as exc:  # rosbags raises ReaderError / AnyReaderError, mcap errors
        raise _read_error(info.path, exc) from None


def bag_config(info: BagInfo, config: Path | None = None) -> tuple[Any, str]:
    """The run's SwarmConfig and timing mode: from ``config`` (a parameter file) or from the
    bag's ``custom_data`` (the bring-up's recorder stores both)."""
    import tempfile

    from apf_swarm_core.config import load_config

    mode = info.custom_data.get(CUSTOM_MODE, 'lockstep')
    if config is not None:
        return load_config(config), mode
    text = info.custom_data.get(CUSTOM_CONFIG)
    if not text:
        raise CliError(
            f'{info.path} has no apf_swarm configuration in its custom_data (not '
            'recorded by `apf-swarm up --record`?); pass --config FILE'
        )
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / 'config.yaml'
        p.write_text(text)
        return load_config(p), mode


def swarm_state_accumulator(info: BagInfo, cfg: Any, mode: str) -> Any:
    """Every ``/swarm/state`` message of the bag through the bring-up's StateAccumulator
    (the same raw-bytes path and deserialization as the live run)."""
    from .bringup import StateAccumulator

    info.topic(SWARM_STATE_TOPIC)
    acc = StateAccumulator(mode, cfg.steps, cfg.record_every)
    for _topic, _type, _ts, raw in iter_raw(info.path, [SWARM_STATE_TOPIC], info=info):
        acc.add_raw(raw)
    return acc


def bag_trajectory(
    path: Path | str, config: Path | None = None
) -> tuple[dict[str, Any], Any, str, Any]:
    """``(trajectory, cfg, mode, accumulator)`` of a bag's ``/swarm/state``."""
    info = open_bag(path)
    cfg, mode = bag_config(info, config)
    acc = swarm_state_accumulator(info, cfg, mode)
    traj = acc.trajectory()
    if traj is None:
        raise CliError(f'{info.path}: /swarm/state has no message; nothing to compute')
    return traj, cfg, mode, acc


def bag_metrics(path: Path | str, config: Path | None = None) -> dict[str, Any]:
    """summary.json of the run from the bag's ``/swarm/state`` (:func:`runio.run_summary`, the
    function the bring-up uses), plus ``messages`` and ``mode``."""
    from .runio import run_summary

    traj, cfg, mode, acc = bag_trajectory(path, config)
    status = 'completed' if mode == 'realtime' or acc.complete else 'incomplete'
    summary = run_summary(
        traj, cfg, status=status, n_samples=len(acc.samples), dropped=acc.dropped
    )
    summary['mode'] = mode
    summary['messages'] = acc.messages()
    return summary


# --------------------------------------------------------------------------------------------
# export
# --------------------------------------------------------------------------------------------


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


def export_csv(path: Path | str, topic: str, out: TextIO) -> int:
    """Flattened fields of every message of ``topic`` as CSV into ``out``; returns the rows.

    Columns: ``timestamp_ns`` (the bag's receive time), then the fields in first-seen order
    (a variable-length array adds columns as it grows; shorter rows leave them empty).
    """
    info = open_bag(path)
    t = info.topic(topic)
    rows: list[dict[str, Any]] = []
    columns: dict[str, None] = {'timestamp_ns': None}
    try:
        with contextlib.closing(_any_reader(info.path)) as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            for conn, ts, raw in reader.messages(connections=conns):
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as exc:
                    raise CliError(
                        f'{topic}: cannot decode type {t.type} '
                        f"({_one_line(exc)}); the bag's definition of it is "
                        'missing or wrong'
                    ) from None
                row = {'timestamp_ns': int(ts), **flatten(msg)}
                for k in row:
                    if k not in columns:
                        columns[k] = None
                rows.append(row)
    except CliError:
        raise
    except Exception as exc:
        raise _read_error(info.path, exc, topic) from None
    w = csv.DictWriter(out, fieldnames=list(columns), restval='', lineterminator='\n')
    w.writeheader()
    w.writerows(rows)
    return len(rows)


# --------------------------------------------------------------------------------------------
# reindex
# --------------------------------------------------------------------------------------------


@dataclass
class _Recovered:
    schemas: dict[int, Any]
    channels: dict[int, Any]
    messages: list[Any]
    metadata: dict[str, str]
    compression: str
    complete: bool
    error: str


def _scan_mcap(file: Path) -> _Recovered:
    """Every schema, channel, message and metadata record up to the first unreadable one."""
    from mcap.records import Channel, Chunk, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk

    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    messages: list[Any] = []
    metadata: dict[str, str] = {}
    compression = ''
    error = ''
    complete = False
    with open(file, 'rb') as f:
        reader = StreamReader(f, emit_chunks=True)
        try:
            for rec in reader.records:
                if isinstance(rec, Chunk):
                    compression = compression or rec.compression
                    inner = breakup_chunk(rec, validate_crc=True)
                else:
                    inner = [rec]
                for r in inner:
                    if isinstance(r, Schema):
                        schemas[r.id] = r
                    elif isinstance(r, Channel):
                        channels[r.id] = r
                    elif isinstance(r, Message):
                        messages.append(r)
                    elif isinstance(r, Metadata) and r.name == MCAP_METADATA_NAME:
                        metadata.update(r.metadata)
            complete = True
        except Exception as exc:  # the truncated tail: EndOfFile, struct.error, zstd errors
            error = f'{type(exc).__name__}: {exc}' if str(exc) else type(exc).__name__
    return _Recovered(schemas, channels, messages, metadata, compression, complete, error)


def _rewrite_mcap(rec: _Recovered, dst: Path, chunk_size: int = DEFAULT_CHUNK_SIZE) -> None:
    """A complete MCAP file (summary, indexes, statistics) with mcap's writer."""
    from mcap.writer import CompressionType, Writer

    comp = CompressionType.ZSTD if rec.compression == 'zstd' else CompressionType.NONE
    with open(dst, 'xb') as f:
        w = Writer(f, chunk_size=chunk_size, compression=comp)
        w.start(profile='ros2', library='apf_swarm reindex (mcap)')
        sid = {
            old: w.register_schema(s.name, s.encoding, s.data)
            for old, s in sorted(rec.schemas.items())
        }
        cid = {}
        for old, c in sorted(rec.channels.items()):
            if c.schema_id and c.schema_id not in sid:
                continue  # its schema was in the lost part (cannot happen with rosbags)
            cid[old] = w.register_channel(
                c.topic, c.message_encoding, sid.get(c.schema_id, 0), dict(c.metadata)
            )
        for m in sorted(rec.messages, key=lambda m: m.log_time):
            if m.channel_id in cid:
                w.add_message(cid[m.channel_id], m.log_time, m.data, m.publish_time, m.sequence)
        if rec.metadata:
            w.add_metadata(MCAP_METADATA_NAME, dict(rec.metadata))
        w.finish()


def _hash_of(schema: Any, fallback: str = '') -> str:
    if fallback:
        return fallback
    try:
        from rosbags.typesys import get_types_from_msg
        from rosbags.typesys.stores import Stores, get_typestore

        store = get_typestore(Stores.EMPTY)
        text = schema.data.decode()
        store.register(get_types_from_msg(text, schema.name))
        return store.hash_rihs01(schema.name)
    except Exception:
        return ''


def reindex(path: Path | str, *, stream: TextIO | None = None) -> dict[str, Any]:
    """Rebuild metadata.yaml (and the index of every MCAP file that lacks one) from the MCAP
    files of a bag directory.

    An MCAP file without a valid summary (a writer killed by SIGKILL) is read record by record
    up to its truncated tail, i.e. every complete chunk, and rewritten whole with mcap's
    writer. Everything replaced (the old metadata.yaml, the truncated MCAP files) is moved to
    ``BAG/reindex-backup-<UTC time>/``; nothing is deleted. Returns a report mapping.
    """
    say = (lambda s: print(s, file=stream)) if stream is not None else (lambda s: None)
    path = Path(path)
    if not path.exists():
        raise CliError(f'{path}: no such file or directory; pass the bag directory to reindex')
    if not path.is_dir():
        raise CliError(f'{path} is a file; pass the bag directory (with the .mcap files)')
    files = bag_files(path)
    if not files:
        raise CliError(f'{path} is not a bag: it has no .mcap file to rebuild metadata.yaml from')
    old_meta: dict[str, Any] = {}
    if (path / 'metadata.yaml').is_file():
        try:
            old_meta = _read_metadata(path)
        except CliError:
            old_meta = {}
    old_topics = {
        e.get('topic_metadata', {}).get('name'): e.get('topic_metadata', {})
        for e in (old_meta.get('topics_with_message_count') or [])
    }
    backup = path / f'reindex-backup-{time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())}'
    report: dict[str, Any] = {'path': str(path), 'files': [], 'backup': None}

    def backup_dir() -> Path:
        backup.mkdir(exist_ok=True)
        report['backup'] = str(backup)
        return backup

    file_stats: list[dict[str, Any]] = []
    topics: dict[str, dict[str, Any]] = {}
    custom: dict[str, str] = {
        str(k): str(v) for k, v in (old_meta.get('custom_data') or {}).items()
    }
    for file in files:
        rec = _scan_mcap(file)
        if not rec.complete:
            if not rec.schemas and not rec.messages:
                raise CliError(
                    f'{file}: no complete MCAP record could be read ({rec.error}); '
                    'nothing to recover (the recorder died before its first chunk?)'
                )
            tmp = file.with_name(file.name + '.reindex.tmp')
            if tmp.exists():
                tmp.unlink()
            _rewrite_mcap(rec, tmp)
            shutil.move(str(file), str(backup_dir() / file.name))
            tmp.replace(file)
            say(
                f'{file.name}: truncated ({rec.error}); recovered {len(rec.messages)} messages '
                f'of {len(rec.channels)} topics from its complete chunks, rewrote it '
                f'(original in {backup.name}/)'
            )
            action = 'rewritten'
        else:
            say(f'{file.name}: complete, {len(rec.messages)} messages')
            action = 'kept'
        for k, v in rec.metadata.items():
            custom.setdefault(k, v)
        ts = [m.log_time for m in rec.messages]
        file_stats.append(
            {
                'path': file.name,
                'starting_time': {'nanoseconds_since_epoch': min(ts) if ts else 0},
                'duration': {'nanoseconds': (max(ts) - min(ts)) if ts else 0},
                'message_count': len(ts),
            }
        )
        report['files'].append(
            {'path': file.name, 'action': action, 'messages': len(ts), 'error': rec.error}
        )
        per_channel: dict[int, int] = defaultdict(int)
        for m in rec.messages:
            per_channel[m.channel_id] += 1
        for cid_, ch in sorted(rec.channels.items()):
            schema = rec.schemas.get(ch.schema_id)
            t = topics.setdefault(
                ch.topic,
                {
                    'name': ch.topic,
                    'type': schema.name if schema else '',
                    'serialization_format': ch.message_encoding,
                    'offered_qos_profiles': yaml.safe_load(
                        ch.metadata.get('offered_qos_profiles', '') or '[]'
                    )
                    or [],
                    'type_description_hash': _hash_of(
                        schema, old_topics.get(ch.topic, {}).get('type_description_hash', '')
                    )
                    if schema
                    else '',
                    'message_count': 0,
                },
            )
            t['message_count'] += per_channel.get(cid_, 0)
    custom['apf_swarm.reindexed'] = time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())
    doc = build_metadata(
        files=file_stats,
        topics=list(topics.values()),
        custom_data=custom,
        ros_distro=str(old_meta.get('ros_distro', 'rosbags')),
    )
    if (path / 'metadata.yaml').is_file():
        shutil.copy2(path / 'metadata.yaml', backup_dir() / 'metadata.yaml')
    _write_metadata(path / 'metadata.yaml', doc)
    report['messages'] = doc['rosbag2_bagfile_information']['message_count']
    report['topics'] = {t['name']: t['message_count'] for t in topics.values()}
    say(
        f'wrote {path / "metadata.yaml"}: {report["messages"]} messages on {len(topics)} topics'
        + (f'; backup of what was replaced in {backup}' if report['backup'] else '')
    )
    return report
