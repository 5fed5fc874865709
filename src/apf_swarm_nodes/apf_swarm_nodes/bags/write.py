"""Writing a bag (:class:`BagWriter`): raw CDR bytes into rosbag2 MCAP files with mcap's
public writer, flushed chunk by chunk, optionally compressed and split."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from .errors import BagError
from .types import (
    BAG_VERSION,
    DEFAULT_CHUNK_SIZE,
    MCAP_METADATA_NAME,
    ROS_DISTRO,
    _qos_text,
    type_definition,
)

# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------


@dataclass
class Topic:
    """A topic of a bag being written: what :meth:`BagWriter.add_topic` returns and
    :meth:`BagWriter.write` takes."""

    id: int
    topic: str
    msgtype: str
    msgdef: str
    rihs01: str
    offered_qos: list[Any]
    qos_text: str
    count: int = 0


class _McapFile:
    """One MCAP file of a bag, written with mcap's public ``Writer``: the ``ros2`` profile, a
    ``ros2msg`` schema per type, a ``cdr`` channel per topic with its offered QoS, chunks of
    ``chunk_size`` bytes (zstd with ``compress``), and at the end the ``rosbag2``
    ``serialized_metadata`` record that rosbag2 writes."""

    def __init__(self, path: Path, compress: bool, chunk_size: int) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = path
        self._file = path.open('xb')
        self._writer = Writer(
            self._file,
            chunk_size=chunk_size,
            compression=CompressionType.ZSTD if compress else CompressionType.NONE,
        )
        self._writer.start(profile='ros2', library='apf_swarm (mcap)')
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}
        self._pending = 0  # bytes added since the file last grew (the open chunk)
        self._size = 0

    def add_topic(self, t: Topic) -> None:
        sid = self._schemas.get(t.msgtype)
        if sid is None:
            sid = self._schemas[t.msgtype] = self._writer.register_schema(
                t.msgtype, 'ros2msg', t.msgdef.encode()
            )
        self._channels[t.id] = self._writer.register_channel(
            t.topic, 'cdr', sid, {'offered_qos_profiles': t.qos_text}
        )

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """An MCAP Metadata record in the data section (it survives a killed writer)."""
        self._writer.add_metadata(name, dict(data))

    def write(self, t: Topic, timestamp: int, data: bytes | memoryview) -> None:
        self._writer.add_message(self._channels[t.id], timestamp, bytes(data), timestamp)
        size = self._file.tell()
        if size != self._size:
            self._size, self._pending = size, 0
        self._pending += len(data) + 31  # the message record's header

    def file_bytes(self) -> int:
        """The file's size once the open chunk is written (uncompressed estimate)."""
        return self._size + self._pending

    def flush(self, fsync: bool = False) -> None:
        """Close the open chunk (if any) and hand the file's buffer to the OS."""
        self._writer.flush()
        self._size, self._pending = self._file.tell(), 0
        if fsync:
            os.fsync(self._file.fileno())

    def close(self, metadata: str) -> None:
        self._writer.add_metadata(
            'rosbag2', {'ros_distro': ROS_DISTRO, 'serialized_metadata': metadata}
        )
        self._writer.finish()
        self._file.close()


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
    ros_distro: str = ROS_DISTRO,
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
    """Raw CDR messages into a new rosbag2 bag (metadata.yaml v9, MCAP files written by
    mcap's public ``Writer``).

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
        self.files: list[_FileStats] = []
        self.storage: _McapFile | None = None
        self._mcap_metadata: dict[str, str] = {}

    # --- set-up ---------------------------------------------------------------------------
    def open(self) -> BagWriter:
        self.path.mkdir(mode=0o755, parents=True)
        self._new_storage()
        return self

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, *exc: Any) -> None:
        if self.storage is not None:
            self.close()

    def _new_storage(self) -> _McapFile:
        name = f'{self.path.name}_{len(self.files)}.mcap'
        self.files.append(_FileStats(name))
        storage = self.storage = _McapFile(self.path / name, self.compress, self.chunk_size)
        self._file_start: int | None = None
        if self._mcap_metadata:
            storage.add_metadata(MCAP_METADATA_NAME, self._mcap_metadata)
        for t in self.topics:
            storage.add_topic(t)
        return storage

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

        Without ``msgdef`` / ``rihs01`` they come from :func:`type_definition` (BagError for a
        type nobody knows).
        """
        if msgdef is None or rihs01 is None:
            d, h = type_definition(msgtype)
            msgdef, rihs01 = msgdef or d, rihs01 or h
        if any(t.topic == topic for t in self.topics):
            raise BagError(f'{topic} is in the bag already; add each topic once')
        t = Topic(
            len(self.topics) + 1,
            topic,
            msgtype,
            msgdef,
            rihs01,
            list(offered_qos),
            _qos_text(offered_qos),
        )
        self.topics.append(t)
        if self.storage is not None:
            self.storage.add_topic(t)
        return t

    # --- data -----------------------------------------------------------------------------
    def write(self, conn: Topic, timestamp: int, data: bytes | memoryview) -> None:
        """One serialized message at ``timestamp`` (ns since the epoch)."""
        if self.storage is None:
            raise BagError(f'{self.path}: the bag is not open (use BagWriter.open or with)')
        if self._file_start is None:
            self._file_start = timestamp
        elif (self.split_size and self.storage.file_bytes() >= self.split_size) or (
            self.split_ns and timestamp - self._file_start >= self.split_ns
        ):
            self.split()
            self._file_start = timestamp
        assert self.storage is not None
        self.storage.write(conn, timestamp, data)
        conn.count += 1
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
        self._new_storage()

    def _close_storage(self) -> None:
        assert self.storage is not None
        doc = self.metadata()['rosbag2_bagfile_information']
        self.storage.close(yaml.safe_dump(doc, sort_keys=False).strip())
        self.storage = None

    # --- the end --------------------------------------------------------------------------
    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        return {t.topic: t.count for t in self.topics}

    @property
    def written(self) -> int:
        return sum(t.count for t in self.topics)

    def metadata(self) -> dict[str, Any]:
        from rosbags.rosbag2.metadata import dump_qos_v9

        topics = [
            {
                'name': t.topic,
                'type': t.msgtype,
                'serialization_format': 'cdr',
                'offered_qos_profiles': dump_qos_v9(t.offered_qos),
                'type_description_hash': t.rihs01,
                'message_count': t.count,
            }
            for t in self.topics
        ]
        return build_metadata(
            files=[f.as_dict() for f in self.files], topics=topics, custom_data=self.custom_data
        )

    def close(self) -> None:
        """Write the MCAP summary and metadata.yaml."""
        if self.storage is None:
            return
        self._close_storage()
        _write_metadata(self.path / 'metadata.yaml', self.metadata())
