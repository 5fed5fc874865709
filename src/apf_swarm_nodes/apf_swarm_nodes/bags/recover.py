"""``apf-swarm bag reindex``: a bag whose writer was killed made whole again (every
complete record recovered, the summary, indexes and metadata.yaml rebuilt)."""

from __future__ import annotations

import shutil
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import yaml

from .errors import BagError
from .info import _read_metadata, bag_files
from .types import DEFAULT_CHUNK_SIZE, MCAP_METADATA_NAME, ROS_DISTRO
from .write import _write_metadata, build_metadata

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
        raise BagError(f'{path}: no such file or directory; pass the bag directory to reindex')
    if not path.is_dir():
        raise BagError(f'{path} is a file; pass the bag directory (with the .mcap files)')
    files = bag_files(path)
    if not files:
        raise BagError(f'{path} is not a bag: it has no .mcap file to rebuild metadata.yaml from')
    old_meta: dict[str, Any] = {}
    if (path / 'metadata.yaml').is_file():
        try:
            old_meta = _read_metadata(path)
        except BagError:
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
                raise BagError(
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
        ros_distro=str(old_meta.get('ros_distro', ROS_DISTRO)),
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
