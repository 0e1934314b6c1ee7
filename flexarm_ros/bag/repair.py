"""Rewrite a damaged or unfinished MCAP bag into a complete one (``flexarm bag repair``).

A bag whose writer was killed has no summary section and no footer; one with damage
inside has chunks that fail their CRC.  :func:`flexarm_ros.bag.reader.read_bag` reads
such files, but tools that seek through the summary (``mcap``'s indexed reader,
``ros2 bag info``, rosbags) refuse them.  :func:`repair` reads every intact record with
the project's damage-tolerant scanner (:mod:`.salvage`) and writes a new, complete file:

* the same header profile and library, the same schemas (name, encoding, text) and
  channels (topic, message encoding, schema, channel metadata such as the offered QoS),
  in their original order (so the ids of a file written by ``mcap``'s writer stay the
  same), every Metadata record and attachment;
* every recovered message with its log time, publish time, sequence number and bytes
  unchanged, in file order;
* zstd chunks (else lz4, else none) with CRCs, message/chunk/metadata indexes,
  statistics, summary offsets and footer: what :class:`~.writer.BagWriter` writes;
* a fresh ``rosbag2`` Metadata record counting what was recovered (version, custom data
  and ROS distribution taken from the damaged file's record when it survived), and a
  ``flexarm_ros.repair`` Metadata record saying where the file came from and what was
  lost.

Messages from bytes no CRC vouched for (outside chunks, or in chunks without a CRC) are
decoded first and dropped when they do not decode; messages whose Channel or Schema
record was lost cannot be placed and are dropped.  Both are counted in the report.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from mcap.records import Channel, Schema
from mcap.writer import IndexType
from mcap.writer import Writer as _McapWriter

from flexarm_ros import __version__
from flexarm_ros.bag.reader import Decoders, Undecodable
from flexarm_ros.bag.salvage import BagError, Damage, scan, seconds
from flexarm_ros.bag.writer import (INFO_METADATA_NAME, ROSBAG2_METADATA_NAME,
                                    default_compression, dump_yaml, rosbag2_bag_metadata)

__all__ = ["REPAIR_METADATA_NAME", "RepairReport", "default_output", "repair"]

REPAIR_METADATA_NAME = "flexarm_ros.repair"
"""Name of the Metadata record a repaired file carries (source, counts, what was lost)."""


@dataclass
class RepairReport:
    """What :func:`repair` recovered and what it could not."""

    source: str
    output: str
    messages: int = 0
    topics: dict[str, int] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None
    damage: list[Damage] = field(default_factory=list)
    orphans: int = 0                    # messages whose Channel/Schema record was lost
    undecodable: int = 0                # unverified messages that did not decode
    summary_message_count: int | None = None   # the damaged file's own count, if intact

    @property
    def intact(self) -> bool:
        return not self.damage and not self.orphans and not self.undecodable

    def lost_text(self) -> str:
        """What was lost, in one phrase ("nothing" for an intact file)."""
        if self.intact:
            return "nothing (the file was complete)"
        parts = []
        for d in self.damage:
            if d.kind == "truncated":
                if d.reason == "file ends without MCAP footer":
                    parts.append(f"the summary and footer (the file ends at byte {d.start})")
                else:
                    parts.append(f"the tail from byte {d.start} ({d.reason}: the records "
                                 f"being written when the writer stopped, count unknown)")
            else:
                parts.append(d.describe())
        if self.orphans:
            parts.append(f"{self.orphans} messages whose Channel/Schema record was lost")
        if self.undecodable:
            parts.append(f"{self.undecodable} undecodable messages from unchecked bytes")
        return "; ".join(parts)

    def text(self) -> str:
        """One line: ``IN: recovered N [of M] messages (...); lost: ... → OUT``."""
        of = "" if self.summary_message_count is None else f" of {self.summary_message_count}"
        span = "" if self.start_ns is None else \
            f", log time {seconds(self.start_ns)}–{seconds(self.end_ns)} s"
        return (f"{self.source}: recovered {self.messages}{of} messages on "
                f"{len(self.topics)} topics{span}; lost: {self.lost_text()} → {self.output}")

    def as_dict(self) -> dict[str, Any]:
        return {"source": self.source, "output": self.output, "messages": self.messages,
                "topics": dict(self.topics), "start_ns": self.start_ns, "end_ns": self.end_ns,
                "intact": self.intact, "orphans": self.orphans,
                "undecodable": self.undecodable,
                "summary_message_count": self.summary_message_count,
                "damage": [{"start": d.start, "end": d.end, "kind": d.kind,
                            "reason": d.reason, "lost_messages": d.lost_messages,
                            "lost_time_ns": list(d.lost_time_ns) if d.lost_time_ns else None}
                           for d in self.damage]}


def default_output(source: str | os.PathLike) -> Path:
    """``run.mcap`` → ``run.repaired.mcap`` next to it."""
    p = Path(source)
    return p.with_name(f"{p.stem}.repaired{p.suffix or '.mcap'}")


def _version_of(qos_texts: list[str], old: dict | None) -> int:
    """rosbag2 metadata version: the damaged file's, else from the QoS spelling."""
    if old and old.get("version") in (8, 9):
        return int(old["version"])
    for text in qos_texts:
        try:
            qos = yaml.safe_load(text)
        except yaml.YAMLError:
            continue
        if isinstance(qos, list) and qos and isinstance(qos[0], dict):
            return 8 if isinstance(qos[0].get("reliability"), int) else 9
    return 9


def _qos_list(text: str) -> list:
    try:
        qos = yaml.safe_load(text) if text else []
    except yaml.YAMLError:
        return []
    return qos if isinstance(qos, list) else []


def repair(source: str | os.PathLike, output: str | os.PathLike | None = None, *,
           chunk_size: int = 256 * 1024) -> RepairReport:
    """Write the readable content of ``source`` as a complete MCAP file ``output``
    (default ``<stem>.repaired.mcap``) and return the :class:`RepairReport`.

    The output is written to a temporary file in its directory and renamed at the end,
    so an existing file of that name is replaced only by a complete one.  Raises
    :class:`~flexarm_ros.bag.reader.BagError` (empty file, not MCAP, output = input) and
    ``OSError`` (unreadable input, unwritable output).
    """
    src_path = Path(source)
    out = Path(output) if output is not None else default_output(src_path)
    if not src_path.exists():
        raise FileNotFoundError(f"{src_path}: no such file, expected the damaged MCAP bag "
                                f"to repair")
    if src_path.is_dir():
        raise BagError(f"{src_path}: is a directory, expected the .mcap file to repair")
    if out.exists() and os.path.samefile(out, src_path):
        raise BagError(f"{out}: the output must differ from the input (the damaged file "
                       "is kept as it is), expected another path for --out")
    scanner, src = scan(src_path)
    report = RepairReport(str(src_path), str(out))
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp",
                               dir=str(out.parent if str(out.parent) else "."))
    ok = False
    try:
        with os.fdopen(fd, "wb") as f:
            _rewrite(scanner, f, report, out.name, chunk_size)
        os.replace(tmp, out)
        ok = True
    finally:
        src.close()
        if not ok and os.path.exists(tmp):
            os.unlink(tmp)
    return report


def _rewrite(scanner, f, report: RepairReport, out_name: str, chunk_size: int) -> None:
    decode = Decoders(scanner.name)
    writer: _McapWriter | None = None
    schema_ids: dict[int, int] = {}       # old id -> new id
    channel_ids: dict[int, int] = {}
    channels: dict[int, tuple[Channel, Schema | None]] = {}
    counts: dict[int, int] = {}
    old_rosbag2: dict | None = None
    info: dict[str, str] | None = None

    def start(profile: str, library: str) -> _McapWriter:
        w = _McapWriter(f, chunk_size=chunk_size, compression=default_compression(),
                        index_types=IndexType.ALL, use_chunking=True, use_statistics=True,
                        use_summary_offsets=True, repeat_channels=True, repeat_schemas=True,
                        enable_crcs=True)
        w.start(profile=profile, library=library)
        return w

    def schema_id(schema: Schema | None) -> int:
        if schema is None:
            return 0
        if schema.id not in schema_ids:
            schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                           schema.data)
        return schema_ids[schema.id]

    def channel_id(channel: Channel, schema: Schema | None) -> int:
        if channel.id not in channel_ids:
            channel_ids[channel.id] = writer.register_channel(
                channel.topic, channel.message_encoding, schema_id(schema),
                dict(channel.metadata))
            channels[channel.id] = (channel, schema)
            counts.setdefault(channel.id, 0)
        return channel_ids[channel.id]

    def handle(event: tuple) -> None:
        nonlocal old_rosbag2, info
        kind = event[0]
        if kind == "schema":
            schema_id(event[1])
        elif kind == "channel":
            channel_id(event[1], event[2])
        elif kind == "message":
            _, message, channel, schema, where, verified = event
            if not verified:
                try:
                    decode(message, channel, schema, where, False)
                except Undecodable:
                    report.undecodable += 1
                    return
            cid = channel_id(channel, schema)
            writer.add_message(cid, message.log_time, message.data, message.publish_time,
                               message.sequence)
            counts[channel.id] += 1
            report.messages += 1
            t = message.log_time
            report.start_ns = t if report.start_ns is None else min(report.start_ns, t)
            report.end_ns = t if report.end_ns is None else max(report.end_ns, t)
        elif kind == "metadata":
            record = event[1]
            if record.name == ROSBAG2_METADATA_NAME:      # rewritten with the new counts
                try:
                    old_rosbag2 = yaml.safe_load(record.metadata.get("serialized_metadata", ""))
                except yaml.YAMLError:
                    old_rosbag2 = None
                if not isinstance(old_rosbag2, dict):
                    old_rosbag2 = None
                return
            if record.name == INFO_METADATA_NAME:
                info = dict(record.metadata)
            writer.add_metadata(record.name, dict(record.metadata))
        elif kind == "attachment":
            a = event[1]
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        elif kind == "damage":
            report.damage.append(event[1])
        elif kind == "orphans":
            report.orphans += sum(event[1].values())

    events = scanner.events()
    ahead: list[tuple] = []            # up to the header, or what tells the profile
    header = None
    for event in events:
        ahead.append(event)
        if event[0] == "header":
            header = event[1]
            break
        if event[0] == "channel":
            break
    if header is None:      # the header was lost: ROS 2 CDR channels mean a rosbag2
        cdr = any(e[0] == "channel" and e[1].message_encoding == "cdr" for e in ahead)
        writer = start("ros2" if cdr else "", f"flexarm_ros/{__version__} (repair)")
    else:
        writer = start(header.profile, header.library)
    for event in ahead:
        if event[0] != "header":
            handle(event)
    for event in events:
        if event[0] != "header":
            handle(event)
    if scanner.statistics is not None:
        report.summary_message_count = scanner.statistics.message_count
    for cid, n in counts.items():
        if n:
            report.topics[channels[cid][0].topic] = report.topics.get(channels[cid][0].topic,
                                                                        0) + n
    custom = (old_rosbag2 or {}).get("custom_data")
    if info is None and isinstance(custom, dict) and "scene_yaml" in custom:
        # the twin's own record was lost: BagWriter keeps a copy as rosbag2 custom_data
        info = {str(k): str(v) for k, v in custom.items()}
        writer.add_metadata(INFO_METADATA_NAME, info)
    writer.add_metadata(REPAIR_METADATA_NAME, {
        "source": os.path.basename(report.source), "flexarm_ros_version": __version__,
        "messages_recovered": str(report.messages), "lost": report.lost_text()})
    cdr = [(c, s) for c, s in channels.values() if c.message_encoding == "cdr"]
    if cdr or old_rosbag2 is not None:
        version = _version_of([c.metadata.get("offered_qos_profiles", "") for c, _ in cdr],
                              old_rosbag2)
        topics = [(c.topic, s.name if s is not None else "", c.message_encoding,
                   _qos_list(c.metadata.get("offered_qos_profiles", "")),
                   c.metadata.get("topic_type_hash", ""), counts[c.id]) for c, s in cdr]
        custom = custom or info
        meta = rosbag2_bag_metadata(version, topics, report.start_ns, report.end_ns,
                                    [out_name], custom if isinstance(custom, dict) else None,
                                    str((old_rosbag2 or {}).get("ros_distro") or
                                        os.environ.get("ROS_DISTRO", "")))
        writer.add_metadata(ROSBAG2_METADATA_NAME, {"serialized_metadata": dump_yaml(meta)})
    writer.finish()


def cli(args) -> int:
    """``flexarm bag repair IN [--out OUT] [--json]``: 0 written, 2 bad input."""
    import json
    import sys
    try:
        report = repair(args.bag, args.out)
    except BagError as exc:
        print(f"flexarm bag repair: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        text = f"{exc.filename}: {exc.strerror}" if exc.filename and exc.strerror else exc
        print(f"flexarm bag repair: error: {text}", file=sys.stderr)
        return 2
    print(json.dumps(report.as_dict(), indent=2) if args.json else report.text())
    return 0

