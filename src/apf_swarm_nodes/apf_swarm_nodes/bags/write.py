"""Writing a bag (:class:`BagWriter`): raw CDR bytes into rosbag2 MCAP files through mcap's
public ``Writer``, flushed chunk by chunk, optionally compressed and split."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import yaml

from .errors import BagError
from .types import (
    BAG_VERSION,
    DEFAULT_CHUNK_SIZE,
    MCAP_METADATA_NAME,
    ROS_DISTRO,
    qos_text,
    type_definition,
)

__all__ = [
    'BagWriter',
    'FileStats',
    'Topic',
    'build_metadata',
    'mcap_writer',
    'topic_entry',
    'write_metadata',
]


@dataclass
class Topic:
    """A topic of a bag being written: what :meth:`BagWriter.add_topic` returns and
    :meth:`BagWriter.write` takes."""

    topic: str
    msgtype: str
    msgdef: str
    rihs01: str
    offered_qos: list[Any]
    count: int = 0
    channel: int = 0  # its MCAP channel in the current file


@dataclass
class FileStats:
    """One MCAP file of a bag being written (or rebuilt), as metadata.yaml describes it."""

    path: str
    first: int = 0  # the first message's timestamp (split_duration counts from it)
    start: int = 2**63 - 1
    end: int = 0
    count: int = 0

    def as_dict(self) -> dict[str, Any]:
        start = self.start if self.count else 0
        return {
            'path': self.path,
            'starting_time': {'nanoseconds_since_epoch': start},
            'duration': {'nanoseconds': max(0, self.end - start)},
            'message_count': self.count,
        }


def mcap_writer(file: IO[bytes], compress: bool, chunk_size: int, library: str) -> Any:
    """mcap's ``Writer`` started on ``file`` with the ``ros2`` profile (zstd chunks with
    ``compress``)."""
    from mcap.writer import CompressionType, Writer

    comp = CompressionType.ZSTD if compress else CompressionType.NONE
    writer = Writer(file, chunk_size=chunk_size, compression=comp)
    writer.start(profile='ros2', library=library)
    return writer


def topic_entry(
    name: str, msgtype: str, qos: list[Any], rihs01: str, count: int, fmt: str = 'cdr'
) -> dict[str, Any]:
    """A ``topics_with_message_count`` entry of metadata.yaml (``qos``: as metadata.yaml
    writes it)."""
    return {
        'topic_metadata': {
            'name': name,
            'type': msgtype,
            'serialization_format': fmt,
            'offered_qos_profiles': qos,
            'type_description_hash': rihs01,
        },
        'message_count': count,
    }


def build_metadata(
    files: Sequence[FileStats],
    topics: Sequence[Mapping[str, Any]],
    custom_data: Mapping[str, str],
    ros_distro: str = ROS_DISTRO,
) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` document (version 9) of a bag from its ``files``
    and ``topics`` (``topics_with_message_count`` entries)."""
    used = [f for f in files if f.count]
    start = min((f.start for f in used), default=0)
    end = max((f.end for f in used), default=0)
    return {
        'rosbag2_bagfile_information': {
            'version': BAG_VERSION,
            'storage_identifier': 'mcap',
            'relative_file_paths': [f.path for f in files],
            'duration': {'nanoseconds': max(0, end - start)},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': sum(f.count for f in files),
            'topics_with_message_count': list(topics),
            'compression_format': '',
            'compression_mode': '',
            'files': [f.as_dict() for f in files],
            'custom_data': dict(custom_data) or None,
            'ros_distro': ros_distro,
        }
    }


def write_metadata(path: Path, doc: Mapping[str, Any]) -> None:
    """``path`` / metadata.yaml, replaced atomically."""
    tmp = path / 'metadata.yaml.tmp'
    tmp.write_text(yaml.safe_dump(dict(doc), sort_keys=False, default_flow_style=False))
    tmp.replace(path / 'metadata.yaml')


class BagWriter:
    """Raw CDR messages into a new rosbag2 bag ``path`` (which must not exist): metadata.yaml
    v9 and MCAP files (``ros2`` profile, a ``ros2msg`` schema per type, a ``cdr`` channel per
    topic with its offered QoS, the ``rosbag2`` metadata record at the end).

    ``compress``: zstd chunks (``ros2 bag``'s ``zstd_fast``); ``chunk_size``: uncompressed
    bytes per chunk; ``split_size`` / ``split_duration``: a new file ``BAG_<k>.mcap`` after
    this many bytes / seconds of message time (0: never). After :meth:`flush` a kill loses
    nothing written before it (``bag reindex`` rebuilds the rest); :meth:`close` writes the
    summaries and metadata.yaml.
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
        self.path = Path(path)
        if self.path.exists():
            raise BagError(
                f'{self.path} exists already; a bag is never overwritten: choose a new '
                'output directory'
            )
        self.compress = bool(compress)
        self.chunk_size = max(1024, int(chunk_size))
        self.split_size = int(split_size)
        self.split_ns = int(round(split_duration * 1e9))
        self.topics: list[Topic] = []
        self.custom_data: dict[str, str] = {}
        self.files: list[FileStats] = []
        self._early: dict[str, str] = {}  # custom_data also in an MCAP metadata record
        self._file: IO[bytes] | None = None
        self._writer: Any = None
        self._schemas: dict[str, int] = {}
        self._size = self._pending = 0  # file size, bytes added since it last grew

    def open(self) -> BagWriter:
        self.path.mkdir(mode=0o755, parents=True)
        self._new_file()
        return self

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _new_file(self) -> None:
        name = f'{self.path.name}_{len(self.files)}.mcap'
        self.files.append(FileStats(name))
        self._file = (self.path / name).open('xb')
        self._writer = mcap_writer(self._file, self.compress, self.chunk_size, 'apf_swarm (mcap)')
        self._schemas = {}
        self._size = self._pending = 0
        if self._early:
            self._writer.add_metadata(MCAP_METADATA_NAME, dict(self._early))
        for t in self.topics:
            self._register(t)

    def _register(self, t: Topic) -> None:
        sid = self._schemas.get(t.msgtype)
        if sid is None:
            sid = self._schemas[t.msgtype] = self._writer.register_schema(
                t.msgtype, 'ros2msg', t.msgdef.encode()
            )
        meta = {'offered_qos_profiles': qos_text(t.offered_qos)}
        t.channel = self._writer.register_channel(t.topic, 'cdr', sid, meta)

    def set_custom_data(self, key: str, value: str, *, early: bool = False) -> None:
        """A ``custom_data`` entry of metadata.yaml; ``early``: also an MCAP Metadata record
        written now (and at the start of every split file), so that ``reindex`` finds it in a
        bag whose writer was killed."""
        self.custom_data[key] = str(value)
        if early:
            self._early[key] = str(value)
            if self._writer is not None:
                self._writer.add_metadata(MCAP_METADATA_NAME, {key: str(value)})

    def add_topic(
        self,
        topic: str,
        msgtype: str,
        *,
        msgdef: str | None = None,
        rihs01: str | None = None,
        offered_qos: Sequence[Any] = (),
    ) -> Topic:
        """Register a topic; returns the connection to pass to :meth:`write`.

        Without ``msgdef`` / ``rihs01`` they come from :func:`type_definition` (BagError for a
        type nobody knows).
        """
        if msgdef is None or rihs01 is None:
            d, h = type_definition(msgtype)
            msgdef, rihs01 = msgdef or d, rihs01 or h
        if any(t.topic == topic for t in self.topics):
            raise BagError(f'{topic} is in the bag already; add each topic once')
        t = Topic(topic, msgtype, msgdef, rihs01, list(offered_qos))
        self.topics.append(t)
        if self._writer is not None:
            self._register(t)
        return t

    def write(self, conn: Topic, timestamp: int, data: bytes | memoryview) -> None:
        """One serialized message at ``timestamp`` (ns since the epoch)."""
        if self._writer is None:
            raise BagError(f'{self.path}: the bag is not open (use BagWriter.open or with)')
        f = self.files[-1]
        if f.count and (
            (self.split_size and self._size + self._pending >= self.split_size)
            or (self.split_ns and timestamp - f.first >= self.split_ns)
        ):
            self.split()
            f = self.files[-1]
        self._writer.add_message(conn.channel, timestamp, bytes(data), timestamp)
        if self.split_size:  # the file's size once the open chunk is written (uncompressed)
            assert self._file is not None
            if (size := self._file.tell()) != self._size:
                self._size, self._pending = size, 0
            self._pending += len(data) + 31  # the message record's header
        conn.count += 1
        if not f.count:
            f.first = timestamp
        f.count += 1
        f.start = min(f.start, timestamp)
        f.end = max(f.end, timestamp)

    def flush(self, fsync: bool = False) -> None:
        """Close the pending chunk and hand it to the OS (``fsync``: also to the disk)."""
        if self._writer is not None:
            self._writer.flush()
            if fsync:
                assert self._file is not None
                os.fsync(self._file.fileno())

    def split(self) -> None:
        """Close the current file and continue in ``BAG_<k+1>.mcap`` (same topics)."""
        self._close_file()
        self._new_file()

    def _close_file(self) -> None:
        assert self._file is not None
        doc = yaml.safe_dump(self.metadata()['rosbag2_bagfile_information'], sort_keys=False)
        self._writer.add_metadata(
            'rosbag2', {'ros_distro': ROS_DISTRO, 'serialized_metadata': doc.strip()}
        )
        self._writer.finish()
        self._file.close()
        self._writer = self._file = None

    def metadata(self) -> dict[str, Any]:
        """metadata.yaml of what is written so far."""
        from rosbags.rosbag2.metadata import dump_qos_v9

        topics = [
            topic_entry(t.topic, t.msgtype, dump_qos_v9(t.offered_qos), t.rihs01, t.count)
            for t in self.topics
        ]
        return build_metadata(self.files, topics, self.custom_data)

    def close(self) -> None:
        """Write the MCAP summary and metadata.yaml (again: nothing)."""
        if self._writer is not None:
            self._close_file()
            write_metadata(self.path, self.metadata())
