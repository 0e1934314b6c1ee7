"""Read MCAP bags (ours or foreign) and decode their ROS 2 messages, without ROS.

Contract
--------
:func:`read_bag` and :func:`iter_messages` read any MCAP file sequentially, record by
record, so they need neither the summary section nor the footer: they work on files
written by :class:`~flexarm_ros.bag.writer.BagWriter`, ``ros2 bag record -s mcap``,
rosbags, ``mcap_ros2.writer.Writer`` and other MCAP writers, chunked or not,
compressed (zstd, lz4) or not.  Every message of a channel with message encoding
``cdr`` and a ``ros2msg`` schema is decoded with ``mcap_ros2.decoder.DecoderFactory``
(attribute access, e.g. ``msg.header.stamp.sec``; :func:`to_dict` turns one into plain
dicts/lists); messages of other encodings are returned as raw ``bytes``.  Messages come
in file order, which is recording order for rosbag2 and :class:`BagWriter`.

Damaged files
-------------
Nothing readable is given up because of damage elsewhere in the file:

* **Truncated** (writer killed, disk full, copy interrupted): every message of the
  complete records before the cut is returned and a :class:`TruncatedBagWarning` names
  the file, the byte where reading stopped and how many messages were recovered.
* **Corrupt inside** (a flipped byte, garbage written over a range, bytes inserted or
  deleted): a chunk failing its CRC, its decompression or its record structure, and a
  malformed record, are skipped and reading continues with the next valid record; when
  the record framing itself is destroyed the reader scans forward for the next valid
  record (a known opcode with a plausible length whose body parses, checked against the
  record after it; a chunk must also pass its CRC).  Each damaged region gives a
  :class:`CorruptChunkWarning` (a subclass of :class:`TruncatedBagWarning`) with its
  byte range and, when the file says so (the message index records that follow a
  chunk, the chunk's header, the summary's chunk index), how many messages it held and
  their log-time range.  Messages whose Channel or Schema record was lost with such a
  region cannot be decoded; they are skipped and counted in a warning.  A summary
  section, when present and intact, supplies lost Channel and Schema records.
* :attr:`Bag.damage` lists every region (:class:`Damage`); :attr:`Bag.truncated` is
  true when any warning was issued.

An empty file and a file that is not MCAP (wrong magic) raise :class:`BagError` (a
``ValueError``) naming the file and the problem, as do messages in the intact part that
cannot be decoded with their (intact) schema.  No other exception escapes for any
content of the file.  ``flexarm bag repair`` (:mod:`flexarm_ros.bag.repair`) rewrites
what is readable into a complete file for tools that need the summary.  The scanner
that finds the intact records is :mod:`flexarm_ros.bag.salvage`; this module decodes
their messages and says what was lost.
"""

from __future__ import annotations

import contextlib
import io
import warnings
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import yaml
from mcap.records import Channel, Message, Schema
from mcap_ros2.decoder import DecoderFactory

# BagError, Damage, scan and seconds are the scanner's, importable from here as before
from flexarm_ros.bag.salvage import (  # noqa: F401
    BagError, Damage, Scanner, Source, scan, seconds)

__all__ = [
    "Bag",
    "BagError",
    "BagMessage",
    "CorruptChunkWarning",
    "Damage",
    "TruncatedBagWarning",
    "iter_messages",
    "read_bag",
    "to_dict",
]

_MAX_WARNINGS = 10                      # damaged regions warned one by one, then summed up


class TruncatedBagWarning(UserWarning):
    """The bag ends early or has unreadable parts; everything readable was returned."""


class CorruptChunkWarning(TruncatedBagWarning):
    """A damaged region inside the bag (a chunk failing its CRC or decompression, a
    malformed record, garbage bytes) was skipped and reading went on after it; the text
    names the byte range and what was lost, when the file says so."""


class BagMessage(NamedTuple):
    """One message as yielded by :func:`iter_messages`."""

    topic: str
    msgtype: str
    log_time_ns: int
    publish_time_ns: int
    message: Any


@dataclass
class Bag:
    """Contents of a bag as returned by :func:`read_bag`.

    ``messages[topic]`` is the list of ``(log_time_ns, decoded message)`` in file order
    (every channel of the file has an entry, possibly empty),
    ``types[topic]`` the schema name (``pkg/msg/Type``), ``metadata[name]`` the key/value
    dict of the MCAP Metadata record(s) of that name (records sharing a name are merged,
    later keys win).  ``truncated`` tells whether a :class:`TruncatedBagWarning` (or
    :class:`CorruptChunkWarning`) was issued, ``damage`` lists the unreadable regions,
    ``summary_message_count`` is the message count of the file's summary statistics
    (``None`` without an intact summary).
    """

    path: str
    profile: str = ""
    library: str = ""
    types: dict[str, str] = field(default_factory=dict)
    messages: dict[str, list[tuple[int, Any]]] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: bool = False
    damage: list[Damage] = field(default_factory=list)
    summary_message_count: int | None = None

    @property
    def topics(self) -> list[str]:
        """Topic names, in order of first appearance."""
        return list(self.types)

    @property
    def message_count(self) -> int:
        return sum(len(v) for v in self.messages.values())

    def __getitem__(self, topic: str) -> list[tuple[int, Any]]:
        return self.messages[topic]

    def rosbag2_metadata(self) -> dict[str, Any] | None:
        """The parsed rosbag2 ``BagMetadata`` YAML, or ``None`` if the bag has none."""
        text = self.metadata.get("rosbag2", {}).get("serialized_metadata")
        if text is None:
            return None
        try:
            out = yaml.safe_load(text)
        except yaml.YAMLError:
            return None
        return out if isinstance(out, dict) else None


def to_dict(msg: Any) -> Any:
    """Convert a decoded message (nested) to plain dicts and lists."""
    slots = getattr(type(msg), "__slots__", None)
    if slots and hasattr(msg, "_type"):
        return {name: to_dict(getattr(msg, name)) for name in slots}
    if isinstance(msg, (list, tuple)):
        return [to_dict(v) for v in msg]
    return msg


# ---------------------------------------------------------------------------- decoding

class Undecodable(Exception):
    """A message from unverified bytes (no CRC) failed to decode."""


class Decoders:
    """ROS 2 CDR decoders per channel.  A failure on bytes a chunk CRC vouched for is an
    incompatibility (:class:`BagError`); on unverified bytes it is damage
    (:class:`Undecodable`, the caller skips the message and counts it)."""

    def __init__(self, name: str):
        self.name = name
        self.factory = DecoderFactory()
        self.cache: dict[int, Any] = {}

    def __call__(self, message: Message, channel: Channel, schema: Schema | None,
                 where: int, verified: bool) -> Any:
        msgtype = schema.name if schema is not None else ""
        decoder = self.cache.get(channel.id)
        if decoder is None and channel.id not in self.cache:
            try:
                with contextlib.redirect_stderr(io.StringIO()):   # the parser prints
                    decoder = self.factory.decoder_for(channel.message_encoding, schema)
            except Exception as err:
                decoder = BagError(f"{self.name}: cannot parse the schema {msgtype!r} of "
                                   f"topic {channel.topic!r}: {err}")
            self.cache[channel.id] = decoder
        if isinstance(decoder, BagError):
            if verified:
                raise decoder
            raise Undecodable(str(decoder))
        try:
            return message.data if decoder is None else decoder(message.data)
        except Exception as err:
            text = (f"{self.name}: cannot decode a {msgtype or 'schemaless'} message on topic "
                    f"{channel.topic!r} (log time {message.log_time} ns, record at byte "
                    f"{where}): {err}")
            if verified:
                raise BagError(text) from err
            raise Undecodable(text) from None


# ---------------------------------------------------------------------------- reading

def _iter(source: Any, topics: Iterable[str] | None, bag: Bag | None,
          stacklevel: int) -> Iterator[BagMessage]:
    wanted = None if topics is None else ({topics} if isinstance(topics, str) else set(topics))
    src = Source(source)
    name = src.name
    if bag is not None:
        bag.path = name
    decoders = Decoders(name)
    count = 0
    warned = 0
    silent: list[Damage] = []
    undecodable: dict[str, list] = {}
    scanner = Scanner(src)
    on = "" if wanted is None else " on the selected topics"

    def warn(text: str, category: type = CorruptChunkWarning) -> None:
        if bag is not None:
            bag.truncated = True
        warnings.warn(text, category, stacklevel=stacklevel + 1)

    try:
        for event in scanner.events():
            kind = event[0]
            if kind == "message":
                _, message, channel, schema, where, verified = event
                if wanted is not None and channel.topic not in wanted:
                    continue
                try:
                    value = decoders(message, channel, schema, where, verified)
                except Undecodable as err:
                    undecodable.setdefault(channel.topic, []).append(str(err))
                    continue
                if bag is not None:
                    bag.messages[channel.topic].append((message.log_time, value))
                count += 1
                yield BagMessage(channel.topic, schema.name if schema is not None else "",
                                 message.log_time, message.publish_time, value)
            elif kind == "channel":
                _, channel, schema = event
                if bag is not None and (wanted is None or channel.topic in wanted):
                    bag.types.setdefault(channel.topic, schema.name if schema is not None
                                         else "")
                    bag.messages.setdefault(channel.topic, [])
            elif kind == "metadata":
                if bag is not None:
                    bag.metadata.setdefault(event[1].name, {}).update(event[1].metadata)
            elif kind == "header":
                if bag is not None:
                    bag.profile, bag.library = event[1].profile, event[1].library
            elif kind == "damage":
                d = event[1]
                if bag is not None:
                    bag.damage.append(d)
                if d.kind == "truncated" or d.end >= scanner.size:
                    what = "truncated" if d.kind == "truncated" else "damaged"
                    why = ("; the writer was probably killed before closing it"
                           if d.kind == "truncated" else "")
                    lost = "" if d.lost_messages is None or d.kind == "truncated" else \
                        f"; {d.lost_messages} messages lost"
                    warn(f"{name}: MCAP bag is {what} at byte {d.start} of {scanner.size} "
                         f"({d.reason}){lost}; recovered {count} messages{on} from the "
                         f"complete records before it{why}",
                         TruncatedBagWarning if d.kind == "truncated" else CorruptChunkWarning)
                elif warned < _MAX_WARNINGS:
                    warned += 1
                    warn(f"{name}: MCAP bag is damaged at byte {d.start} of {scanner.size}: "
                         f"skipped {d.describe()}; read on after it")
                else:
                    silent.append(d)
            elif kind == "orphans":
                n = sum(event[1].values())
                ids = ", ".join(str(i) for i in sorted(event[1]))
                warn(f"{name}: {n} messages on channel id(s) {ids} skipped: their Channel or "
                     f"Schema record was lost in a damaged region")
        for topic, errors in undecodable.items():
            warn(f"{name}: {len(errors)} messages on topic {topic!r} outside any CRC-checked "
                 f"chunk could not be decoded and were skipped (damaged bytes); the first: "
                 f"{errors[0].split(': ', 1)[-1]}")
        if silent:
            lost = [d.lost_messages for d in silent]
            known = sum(x for x in lost if x is not None)
            warn(f"{name}: {len(silent)} more damaged regions skipped (bytes "
                 f"{silent[0].start}–{silent[-1].end}): {known} messages lost"
                 f"{' at least' if None in lost else ''}")
        stats = scanner.statistics
        if bag is not None and stats is not None:
            bag.summary_message_count = stats.message_count
        if stats is not None and not scanner.damage and not scanner.orphans and \
                scanner.messages < stats.message_count:
            warn(f"{name}: its summary counts {stats.message_count} messages, only "
                 f"{scanner.messages} were found in the data section")
    finally:
        src.close()


def iter_messages(path: Any, topics: Iterable[str] | str | None = None) -> Iterator[BagMessage]:
    """Yield :class:`BagMessage` tuples of ``path`` (as for :func:`read_bag`).

    ``topics`` restricts to those topic names.  Damage handling as in :func:`read_bag`
    (each warning comes when the reader has passed the damaged region).
    """
    return _iter(path, topics, None, 2)


def read_bag(path: Any) -> Bag:
    """Read and decode a whole MCAP bag.

    ``path``: an ``.mcap`` file, a rosbag2 directory holding exactly one ``.mcap``
    file, ``bytes`` or a readable binary stream.
    """
    bag = Bag(path="")
    for _ in _iter(path, None, bag, 3):
        pass
    return bag
