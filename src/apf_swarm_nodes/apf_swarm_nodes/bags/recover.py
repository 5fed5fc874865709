"""``apf-swarm bag reindex``: a bag whose writer was killed made whole again (every
complete record recovered, the summary, indexes and metadata.yaml rebuilt)."""

from __future__ import annotations

import contextlib
import shutil
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import yaml

from .errors import BagError
from .info import bag_files, read_metadata
from .types import DEFAULT_CHUNK_SIZE, MCAP_METADATA_NAME, ROS_DISTRO, one_line
from .write import FileStats, build_metadata, mcap_writer, topic_entry, write_metadata

__all__ = ['reindex']


@dataclass
class _Recovered:
    """What an MCAP file holds up to its first unreadable record."""

    schemas: dict[int, Any] = field(default_factory=dict)
    channels: dict[int, Any] = field(default_factory=dict)
    messages: list[Any] = field(default_factory=list)
    metadata: dict[str, str] = field(default_factory=dict)  # our MCAP metadata records
    compression: str = ''
    complete: bool = False
    error: str = ''


def _scan_mcap(file: Path) -> _Recovered:
    """Every schema, channel, message and metadata record up to the first unreadable one."""
    from mcap.records import Channel, Chunk, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk

    out = _Recovered()
    with open(file, 'rb') as f:
        try:
            for rec in StreamReader(f, emit_chunks=True).records:
                if isinstance(rec, Chunk):
                    out.compression = out.compression or rec.compression
                inner = breakup_chunk(rec, validate_crc=True) if isinstance(rec, Chunk) else [rec]
                for r in inner:
                    if isinstance(r, Schema):
                        out.schemas[r.id] = r
                    elif isinstance(r, Channel):
                        out.channels[r.id] = r
                    elif isinstance(r, Message):
                        out.messages.append(r)
                    elif isinstance(r, Metadata) and r.name == MCAP_METADATA_NAME:
                        out.metadata.update(r.metadata)
            out.complete = True
        except Exception as exc:  # the truncated tail: EndOfFile, struct.error, zstd errors
            out.error = one_line(exc)
    return out


def _rewrite_mcap(rec: _Recovered, dst: Path) -> None:
    """A complete MCAP file (summary, indexes, statistics) with mcap's writer."""
    with open(dst, 'xb') as f:
        w = mcap_writer(
            f, rec.compression == 'zstd', DEFAULT_CHUNK_SIZE, 'apf_swarm reindex (mcap)'
        )
        sid = {
            old: w.register_schema(s.name, s.encoding, s.data)
            for old, s in sorted(rec.schemas.items())
        }
        cid = {
            old: w.register_channel(
                c.topic, c.message_encoding, sid.get(c.schema_id, 0), dict(c.metadata)
            )
            for old, c in sorted(rec.channels.items())
            if not c.schema_id or c.schema_id in sid  # a schema in the lost part: dropped
        }
        for m in sorted(rec.messages, key=lambda m: m.log_time):
            if m.channel_id in cid:
                w.add_message(cid[m.channel_id], m.log_time, m.data, m.publish_time, m.sequence)
        if rec.metadata:
            w.add_metadata(MCAP_METADATA_NAME, dict(rec.metadata))
        w.finish()


def _hash_of(schema: Any) -> str:
    """The RIHS01 hash of a stored ``ros2msg`` definition ('' when it cannot be parsed)."""
    from rosbags.typesys import get_types_from_msg
    from rosbags.typesys.stores import Stores, get_typestore

    try:
        store = get_typestore(Stores.EMPTY)
        store.register(get_types_from_msg(schema.data.decode(), schema.name))
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
    meta_file = path / 'metadata.yaml'
    old_meta: dict[str, Any] = {}
    if meta_file.is_file():
        with contextlib.suppress(BagError):
            old_meta = read_metadata(path)
    old_topics = [
        e.get('topic_metadata', {}) for e in old_meta.get('topics_with_message_count') or []
    ]
    old_hash = {tm.get('name'): tm.get('type_description_hash', '') for tm in old_topics}
    backup = path / f'reindex-backup-{time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())}'
    report: dict[str, Any] = {'path': str(path), 'files': [], 'backup': None}
    file_stats: list[FileStats] = []
    topics: dict[str, dict[str, Any]] = {}
    custom = {str(k): str(v) for k, v in (old_meta.get('custom_data') or {}).items()}
    for file in files:
        rec = _scan_mcap(file)
        action = 'kept' if rec.complete else 'rewritten'
        if rec.complete:
            say(f'{file.name}: complete, {len(rec.messages)} messages')
        elif not rec.schemas and not rec.messages:
            raise BagError(
                f'{file}: no complete MCAP record could be read ({rec.error}); '
                'nothing to recover (the recorder died before its first chunk?)'
            )
        else:
            tmp = file.with_name(file.name + '.reindex.tmp')
            tmp.unlink(missing_ok=True)
            _rewrite_mcap(rec, tmp)
            backup.mkdir(exist_ok=True)
            report['backup'] = str(backup)
            shutil.move(str(file), str(backup / file.name))
            tmp.replace(file)
            say(
                f'{file.name}: truncated ({rec.error}); recovered {len(rec.messages)} messages '
                f'of {len(rec.channels)} topics from its complete chunks, rewrote it '
                f'(original in {backup.name}/)'
            )
        for k, v in rec.metadata.items():
            custom.setdefault(k, v)
        ts = [m.log_time for m in rec.messages]
        file_stats.append(FileStats(file.name, 0, min(ts, default=0), max(ts, default=0), len(ts)))
        report['files'].append(
            {'path': file.name, 'action': action, 'messages': len(ts), 'error': rec.error}
        )
        per_channel = Counter(m.channel_id for m in rec.messages)
        for cid, ch in sorted(rec.channels.items()):
            schema = rec.schemas.get(ch.schema_id)
            qos = yaml.safe_load(ch.metadata.get('offered_qos_profiles', '') or '[]') or []
            rihs01 = old_hash.get(ch.topic) or (_hash_of(schema) if schema else '')
            msgtype = schema.name if schema else ''
            t = topics.setdefault(
                ch.topic, topic_entry(ch.topic, msgtype, qos, rihs01, 0, ch.message_encoding)
            )
            t['message_count'] += per_channel[cid]
    custom['apf_swarm.reindexed'] = time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())
    doc = build_metadata(
        file_stats, list(topics.values()), custom, str(old_meta.get('ros_distro', ROS_DISTRO))
    )
    if meta_file.is_file():
        backup.mkdir(exist_ok=True)
        report['backup'] = str(backup)
        shutil.copy2(meta_file, backup / 'metadata.yaml')
    write_metadata(path, doc)
    report['messages'] = doc['rosbag2_bagfile_information']['message_count']
    report['topics'] = {name: t['message_count'] for name, t in topics.items()}
    say(
        f'wrote {meta_file}: {report["messages"]} messages on {len(topics)} topics'
        + (f'; backup of what was replaced in {backup}' if report['backup'] else '')
    )
    return report
