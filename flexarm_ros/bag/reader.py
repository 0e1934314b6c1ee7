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

Damaged files: a file that ends early (writer killed, disk full, copy interrupted) or
whose tail is unreadable (bad record length, chunk failing its CRC or decompression) is
read up to the last complete record; every message of the complete chunks is returned
and a :class:`TruncatedBagWarning` names the file, the byte offset where reading
stopped and how many messages were recovered.  An empty file, a file that is not MCAP
(wrong magic) and undecodable messages in the readable part raise :class:`BagError`
(a ``ValueError``) naming the file and the problem.
"""

from __future__ import annotations

import io
import os
import warnings
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import IO, Any, NamedTuple

import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap_ros2.decoder import DecoderFactory

__all__ = [
    "Bag",
    "BagError",
    "BagMessage",
    "TruncatedBagWarning",
    "iter_messages",
    "read_bag",
    "to_dict",
]

_MAGIC = b"\x89MCAP0\r\n"
_RECORD_LIMIT = 4 * 2**30  # same default bound as mcap's readers


class BagError(ValueError):
    """The file is empty, not an MCAP file, or holds messages that cannot be decoded."""


class TruncatedBagWarning(UserWarning):
    """The bag ends early or has an unreadable tail; the readable prefix was returned."""


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
    later keys win).  ``truncated`` tells whether a :class:`TruncatedBagWarning` was
    issued.
    """

    path: str
    profile: str = ""
    library: str = ""
    types: dict[str, str] = field(default_factory=dict)
    messages: dict[str, list[tuple[int, Any]]] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: bool = False

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
        return None if text is None else yaml.safe_load(text)


def to_dict(msg: Any) -> Any:
    """Convert a decoded message (nested) to plain dicts and lists."""
    slots = getattr(type(msg), "__slots__", None)
    if slots and hasattr(msg, "_type"):
        return {name: to_dict(getattr(msg, name)) for name in slots}
    if isinstance(msg, (list, tuple)):
        return [to_dict(v) for v in msg]
    return msg


class _Stop(Exception):
    """Internal: reading must stop at ``offset`` because of ``reason``."""

    def __init__(self, offset: int, reason: str, damaged: bool = False):
        super().__init__(offset, reason)
        self.offset = offset
        self.reason = reason
        self.damaged = damaged


def _open(source: Any) -> tuple[IO[bytes], str, bool]:
    """(stream, display name, whether we own the stream)."""
    if isinstance(source, (str, os.PathLike)):
        name = os.fspath(source)
        if os.path.isdir(name):  # a rosbag2 bag directory holding one .mcap file
            files = sorted(f for f in os.listdir(name) if f.endswith(".mcap"))
            if len(files) != 1:
                raise BagError(f"{name}: is a directory with {len(files)} .mcap files; "
                               "pass the .mcap file to read")
            name = os.path.join(name, files[0])
        return open(name, "rb"), name, True  # noqa: SIM115 - closed by the caller
    if isinstance(source, (bytes, bytearray, memoryview)):
        return io.BytesIO(bytes(source)), "<bytes>", True
    if hasattr(source, "read"):
        return source, str(getattr(source, "name", "<stream>")), False
    raise TypeError(f"expected a path, bytes or a binary stream, got {type(source).__name__}")


def _remaining(stream: IO[bytes]) -> int | None:
    try:
        pos = stream.tell()
        end = stream.seek(0, io.SEEK_END)
        stream.seek(pos)
        return end - pos
    except (AttributeError, OSError, ValueError):
        return None


class _Scanner:
    """Sequential, damage-tolerant MCAP record reader."""

    def __init__(self, stream: IO[bytes], name: str):
        self.stream = stream
        self.name = name
        self.offset = 0
        self.size = None
        remaining = _remaining(stream)
        if remaining is not None:
            self.size = remaining  # bytes from the current position

    def _read(self, n: int) -> bytes:
        data = self.stream.read(n)
        self.offset += len(data)
        return data

    def magic(self) -> None:
        data = self._read(8)
        if not data:
            raise BagError(f"{self.name}: empty file, not an MCAP bag")
        if data != _MAGIC[:len(data)]:
            raise BagError(f"{self.name}: not an MCAP file (starts with {data!r}, expected "
                           f"the MCAP magic {_MAGIC!r})")
        if len(data) < 8:
            raise _Stop(0, "file ends inside the MCAP magic")

    def records(self) -> Iterator[tuple[int, bytes, int]]:
        """Yield (opcode, body, record offset) until the footer; raise _Stop on damage."""
        while True:
            start = self.offset
            head = self._read(9)
            if not head:
                raise _Stop(start, "file ends without MCAP footer")
            if len(head) < 9:
                raise _Stop(start, "file ends inside a record header")
            opcode = head[0]
            length = int.from_bytes(head[1:], "little")
            left = None if self.size is None else self.size - self.offset
            if length > _RECORD_LIMIT:
                raise _Stop(start, f"implausible record length {length}", damaged=True)
            if left is not None and length > left:
                raise _Stop(start, f"file ends inside a record of {length} bytes "
                                   f"({left} left)")
            body = self._read(length)
            if len(body) < length:
                raise _Stop(start, "file ends inside a record")
            yield opcode, body, start
            if opcode == Opcode.FOOTER:
                tail = self._read(8)
                if tail != _MAGIC:
                    raise _Stop(self.offset - len(tail), "footer not followed by MCAP magic",
                                damaged=bool(tail))
                return


def _parse(cls: Any, body: bytes, *args: Any) -> Any:
    return cls.read(ReadDataStream(io.BytesIO(body)), *args)


def _iter(source: Any, topics: Iterable[str] | None, bag: Bag | None,
          stacklevel: int) -> Iterator[BagMessage]:
    wanted = None if topics is None else ({topics} if isinstance(topics, str) else set(topics))
    stream, name, owned = _open(source)
    if bag is not None:
        bag.path = name
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decoders: dict[int, Any] = {}
    factory = DecoderFactory()
    count = 0

    def decode(message: Message, where: int) -> BagMessage | None:
        channel = channels.get(message.channel_id)
        if channel is None:
            raise BagError(f"{name}: message at byte {where} refers to unknown channel "
                           f"{message.channel_id}")
        if wanted is not None and channel.topic not in wanted:
            return None
        schema = schemas.get(channel.schema_id)
        msgtype = schema.name if schema is not None else ""
        if channel.id not in decoders:
            try:
                decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
            except Exception as err:
                raise BagError(f"{name}: cannot parse the schema {msgtype!r} of topic "
                               f"{channel.topic!r}: {err}") from err
        decoder = decoders[channel.id]
        try:
            value = message.data if decoder is None else decoder(message.data)
        except Exception as err:
            raise BagError(f"{name}: cannot decode a {msgtype or 'schemaless'} message on "
                           f"topic {channel.topic!r} (log time {message.log_time} ns, record "
                           f"at byte {where}): {err}") from err
        if bag is not None:
            bag.messages[channel.topic].append((message.log_time, value))
        return BagMessage(channel.topic, msgtype, message.log_time, message.publish_time, value)

    def handle(opcode: int, record: Any, where: int) -> BagMessage | None:
        if opcode == Opcode.SCHEMA:
            schemas[record.id] = record
        elif opcode == Opcode.CHANNEL:
            if record.schema_id != 0 and record.schema_id not in schemas:
                raise BagError(f"{name}: channel {record.topic!r} at byte {where} refers to "
                               f"unknown schema {record.schema_id}")
            channels[record.id] = record
            if bag is not None and (wanted is None or record.topic in wanted):
                schema = schemas.get(record.schema_id)
                bag.types.setdefault(record.topic, schema.name if schema is not None else "")
                bag.messages.setdefault(record.topic, [])
        elif opcode == Opcode.MESSAGE:
            return decode(record, where)
        return None

    scanner = _Scanner(stream, name)
    try:
        try:
            scanner.magic()
            first = True
            for opcode, body, where in scanner.records():
                try:
                    if first:
                        if opcode != Opcode.HEADER:
                            raise BagError(f"{name}: not a valid MCAP file (first record has "
                                           f"opcode {opcode:#04x}, expected a Header)")
                        header = _parse(Header, body)
                        if bag is not None:
                            bag.profile, bag.library = header.profile, header.library
                        first = False
                        continue
                    if opcode == Opcode.SCHEMA:
                        handle(opcode, _parse(Schema, body), where)
                    elif opcode == Opcode.CHANNEL:
                        handle(opcode, _parse(Channel, body), where)
                    elif opcode == Opcode.MESSAGE:
                        out = handle(opcode, _parse(Message, body, len(body)), where)
                        if out is not None:
                            count += 1
                            yield out
                    elif opcode == Opcode.CHUNK:
                        try:
                            inner = breakup_chunk(_parse(Chunk, body), validate_crc=True)
                        except BagError:
                            raise
                        except Exception as err:
                            raise _Stop(where, f"unreadable chunk: {err}", damaged=True) from err
                        decoded = []
                        for record in inner:
                            opc = {Schema: Opcode.SCHEMA, Channel: Opcode.CHANNEL,
                                   Message: Opcode.MESSAGE}.get(type(record))
                            if opc is not None:
                                out = handle(opc, record, where)
                                if out is not None:
                                    decoded.append(out)
                        for out in decoded:
                            count += 1
                            yield out
                    elif opcode == Opcode.METADATA:
                        meta = _parse(Metadata, body)
                        if bag is not None:
                            bag.metadata.setdefault(meta.name, {}).update(meta.metadata)
                    elif opcode == Opcode.FOOTER:
                        _parse(Footer, body)
                except (BagError, _Stop):
                    raise
                except Exception as err:  # malformed record body
                    raise _Stop(where, f"malformed record with opcode {opcode:#04x} "
                                       f"({type(err).__name__}: {err})", damaged=True) from err
        except _Stop as stop:
            if bag is not None:
                bag.truncated = True
            on = "" if wanted is None else " on the selected topics"
            what, why = (("damaged", "") if stop.damaged else
                         ("truncated", "; the writer was probably killed before closing it"))
            warnings.warn(
                f"{name}: MCAP bag is {what} at byte {stop.offset}"
                f"{'' if scanner.size is None else f' of {scanner.size}'} ({stop.reason}); "
                f"recovered {count} messages{on} from the complete records before it{why}",
                TruncatedBagWarning, stacklevel=stacklevel)
    finally:
        if owned:
            stream.close()


def iter_messages(path: Any, topics: Iterable[str] | str | None = None) -> Iterator[BagMessage]:
    """Yield :class:`BagMessage` tuples of ``path`` (as for :func:`read_bag`).

    ``topics`` restricts to those topic names.  Damage handling as in :func:`read_bag`
    (the :class:`TruncatedBagWarning` comes once the readable part is exhausted).
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
