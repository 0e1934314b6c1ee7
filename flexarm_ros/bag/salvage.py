"""The damage-tolerant MCAP scanner: every intact record of a bag, whatever happened to
the rest of the file (what :func:`~flexarm_ros.bag.reader.read_bag` and ``flexarm bag
repair`` (:mod:`.repair`) read through).

:class:`Scanner` reads the file sequentially, record by record, and needs neither the
summary section nor the footer; :meth:`Scanner.events` yields the records it could read
and a :class:`Damage` for every region it could not.  A chunk failing its CRC, its
decompression or its record structure, and a malformed record, are skipped; when the
record framing itself is destroyed the scanner searches forward for the next valid record
(a known opcode with a plausible length whose body parses, checked against the record
after it; a chunk must also pass its CRC).  What a damaged region held is taken from the
message index records after it, the chunk's header or the summary's chunk index; an
intact summary section (found through the footer, or after the last DataEnd record when
bytes were inserted or deleted before it) supplies lost Channel and Schema records.

Only an empty file and a file that is not MCAP raise (:class:`BagError`); decoding the
messages and warning about the damage is the reader's (:mod:`.reader`).
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import IO, Any, NamedTuple

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (Attachment, Channel, ChunkIndex, Footer, Header, Message, MessageIndex,
                          Metadata, MetadataIndex, Schema, Statistics)

__all__ = ["BagError", "Damage", "Scanner", "Source", "scan", "seconds"]

_MAGIC = b"\x89MCAP0\r\n"
_RECORD_LIMIT = 4 * 2**30  # same default bound as mcap's readers
_OPCODES = frozenset(int(o) for o in Opcode)
_HEAD = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")           # channel id, sequence, log time, publish time
_CHUNK = struct.Struct("<QQQI")         # start/end time, uncompressed size, crc
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_FOOTER_LEN = 9 + 20
_WINDOW = 1 << 16                       # bytes scanned per step when resynchronizing
_DATA_END = _HEAD.pack(Opcode.DATA_END, 4)
_SUMMARY_LOOKBACK = 16 << 20            # bytes searched backwards for a displaced summary


class BagError(ValueError):
    """The file is empty, not an MCAP file, or holds messages that cannot be decoded."""


@dataclass(frozen=True)
class Damage:
    """One unreadable region of a bag: bytes ``[start, end)``.

    ``kind`` is ``"truncated"`` (the file ends inside or right after a complete record,
    without its footer) or ``"corrupt"``.  ``lost_messages`` is the number of messages
    the region held and ``lost_time_ns`` their (first, last) log time, when the message
    indexes, the chunk header or the summary say so (``None``: unknown);
    ``lost_metadata`` the names of the Metadata records in it (from the summary).
    """

    start: int
    end: int
    kind: str
    reason: str
    lost_messages: int | None = None
    lost_time_ns: tuple[int, int] | None = None
    lost_metadata: tuple[str, ...] = ()

    def describe(self) -> str:
        """``"bytes A–B (reason): N messages lost (log time t0–t1 s)"``."""
        what = f"bytes {self.start}–{self.end} ({self.reason})"
        if self.lost_messages is not None:
            what += f": {self.lost_messages} messages lost"
        elif self.kind == "corrupt":
            what += ": an unknown number of messages lost"
        if self.lost_time_ns is not None:
            a, b = self.lost_time_ns
            what += f" (log time {seconds(a)}–{seconds(b)} s)"
        if self.lost_metadata:
            what += (f"; Metadata record{'s' if len(self.lost_metadata) > 1 else ''} "
                     f"{', '.join(repr(n) for n in self.lost_metadata)} lost")
        return what


def seconds(ns: int) -> str:
    """Nanoseconds as exact decimal seconds: 1349000000 → ``"1.349"``."""
    sign, ns = ("-", -ns) if ns < 0 else ("", ns)
    frac = f"{ns % 10**9:09d}".rstrip("0")
    return f"{sign}{ns // 10**9}" + (f".{frac}" if frac else "")


# ------------------------------------------------------------------------------ input

class Source:
    """Random access to the bytes of a file, bytes or stream (``read(pos, n)``)."""

    def __init__(self, source: Any):
        self._owned: IO[bytes] | None = None
        if isinstance(source, (str, os.PathLike)):
            name = os.fspath(source)
            if os.path.isdir(name):  # a rosbag2 bag directory holding one .mcap file
                files = sorted(f for f in os.listdir(name) if f.endswith(".mcap"))
                if len(files) != 1:
                    raise BagError(f"{name}: is a directory with {len(files)} .mcap files; "
                                   "pass the .mcap file to read")
                name = os.path.join(name, files[0])
            self._owned = open(name, "rb")  # noqa: SIM115 - closed by close()
            self.name = name
            self._f: IO[bytes] = self._owned
            self._base = 0
            self.size = self._f.seek(0, io.SEEK_END)
        elif isinstance(source, (bytes, bytearray, memoryview)):
            self.name = "<bytes>"
            self._f = io.BytesIO(bytes(source))
            self._base, self.size = 0, len(self._f.getbuffer())
        elif hasattr(source, "read"):
            self.name = str(getattr(source, "name", "<stream>"))
            try:
                self._base = source.tell()
                self.size = source.seek(0, io.SEEK_END) - self._base
                self._f = source
            except (AttributeError, OSError, ValueError):   # not seekable: take it all
                self._f = io.BytesIO(source.read())
                self._base, self.size = 0, len(self._f.getbuffer())
        else:
            raise TypeError(f"expected a path, bytes or a binary stream, got "
                            f"{type(source).__name__}")

    def read(self, pos: int, n: int) -> bytes:
        if pos >= self.size or n <= 0:
            return b""
        self._f.seek(self._base + pos)
        return self._f.read(min(n, self.size - pos))

    def close(self) -> None:
        if self._owned is not None:
            self._owned.close()


# ---------------------------------------------------------------------------- parsing

class _Bad(Exception):
    """Internal: a record that cannot be read; ``times`` = the chunk header's time range."""

    def __init__(self, reason: str, times: tuple[int, int] | None = None):
        super().__init__(reason)
        self.reason = reason
        self.times = times


def _parse(cls: Any, body: bytes, *args: Any, exact: bool = False) -> Any:
    """An mcap record class's ``read`` on ``body``; ``_Bad`` when it does not fit."""
    stream = ReadDataStream(io.BytesIO(body))
    try:
        record = cls.read(stream, *args)
    except Exception as err:  # EndOfFile, UnicodeDecodeError, struct.error, ...
        raise _Bad(f"malformed {cls.__name__} record ({type(err).__name__}: {err})") from None
    if exact and stream.count != len(body):
        raise _Bad(f"{cls.__name__} record of {len(body)} bytes holds {stream.count}")
    return record


def _message(body: bytes | memoryview) -> Message:
    if len(body) < _MSG.size:
        raise _Bad(f"Message record of {len(body)} bytes (at least {_MSG.size} expected)")
    cid, seq, log, pub = _MSG.unpack_from(body)
    return Message(channel_id=cid, log_time=log, data=bytes(body[_MSG.size:]),
                   publish_time=pub, sequence=seq)


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if size > _RECORD_LIMIT:
        raise _Bad(f"implausible uncompressed chunk size {size}")
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard
        declared = zstandard.frame_content_size(data)
        if declared not in (-1, size):
            raise _Bad(f"zstd frame declares {declared} bytes, the chunk {size}")
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame
        declared = lz4.frame.get_frame_info(data).get("content_size", 0)
        if declared not in (0, size):
            raise _Bad(f"lz4 frame declares {declared} bytes, the chunk {size}")
        return lz4.frame.decompress(data)
    raise _Bad(f"unsupported chunk compression {compression!r}")


class _Chunk(NamedTuple):
    start: int
    end: int
    records: list[tuple[int, Any]]    # (opcode, Schema | Channel | Message)
    verified: bool                    # its CRC was checked


def _chunk(body: bytes) -> _Chunk:
    """Parse, decompress, CRC-check and split a Chunk record's body."""
    if len(body) < _CHUNK.size + 4:
        raise _Bad(f"Chunk record of {len(body)} bytes")
    start, end, size, crc = _CHUNK.unpack_from(body)
    times = (start, end) if start <= end else None
    pos = _CHUNK.size
    (clen,) = _U32.unpack_from(body, pos)
    pos += 4
    if pos + clen + 8 > len(body):
        raise _Bad(f"chunk compression name of {clen} bytes overruns the record", times)
    try:
        compression = body[pos:pos + clen].decode("utf-8")
    except UnicodeDecodeError:
        raise _Bad("chunk compression name is not text", times) from None
    pos += clen
    (dlen,) = _U64.unpack_from(body, pos)
    pos += 8
    if pos + dlen > len(body):
        raise _Bad(f"chunk data of {dlen} bytes overruns the record", times)
    try:
        data = _decompress(compression, body[pos:pos + dlen], size)
    except _Bad as bad:
        raise _Bad(bad.reason, times) from None
    except Exception as err:
        raise _Bad(f"chunk decompression failed ({type(err).__name__}: {err})", times) from None
    if len(data) != size:
        raise _Bad(f"chunk decompresses to {len(data)} bytes, its header says {size}", times)
    if crc != 0 and zlib.crc32(data) != crc:
        raise _Bad(f"crc validation failed in Chunk, expected: {crc}, calculated: "
                   f"{zlib.crc32(data)}", times)
    view = memoryview(data)
    records: list[tuple[int, Any]] = []
    pos = 0
    try:
        while pos < len(data):
            if pos + 9 > len(data):
                raise _Bad("chunk ends inside a record header")
            opcode, length = _HEAD.unpack_from(data, pos)
            pos += 9
            if length > len(data) - pos:
                raise _Bad(f"a record of {length} bytes overruns its chunk")
            body_ = view[pos:pos + length]
            if opcode == Opcode.MESSAGE:
                records.append((opcode, _message(body_)))
            elif opcode == Opcode.SCHEMA:
                records.append((opcode, _parse(Schema, bytes(body_))))
            elif opcode == Opcode.CHANNEL:
                records.append((opcode, _parse(Channel, bytes(body_))))
            pos += length
    except _Bad as bad:
        raise _Bad(f"chunk records are malformed: {bad.reason}", times) from None
    return _Chunk(start, end, records, crc != 0)


def _attachment(body: bytes) -> Attachment:
    record = _parse(Attachment, body)
    if len(body) >= 4:
        (crc,) = _U32.unpack_from(body, len(body) - 4)
        if crc != 0 and zlib.crc32(body[:-4]) != crc:
            raise _Bad("crc validation failed in Attachment")
    return record


# ---------------------------------------------------------------------------- scanner

class _Region:
    """A damaged region being described (message indexes after it add its losses)."""

    def __init__(self, start: int, end: int, kind: str, reason: str,
                 times: tuple[int, int] | None = None):
        self.start, self.end, self.kind, self.reason = start, end, kind, reason
        self.times = times
        self.indexed: int | None = None
        self.index_times: list[int] = []

    def damage(self, lost: int | None, times: tuple[int, int] | None,
               metadata: tuple[str, ...] = ()) -> Damage:
        if self.indexed is not None:
            lost = self.indexed if lost is None else max(lost, self.indexed)
            if self.index_times:
                times = (min(self.index_times), max(self.index_times))
        return Damage(self.start, self.end, self.kind, self.reason, lost,
                      times if times is not None else self.times, metadata)


class Scanner:
    """Damage-tolerant sequential MCAP reader: :meth:`events` yields

    ``("header", Header)``, ``("schema", Schema)``, ``("channel", Channel, Schema|None)``,
    ``("message", Message, Channel, Schema|None, offset)``, ``("metadata", Metadata)``,
    ``("attachment", Attachment)``, ``("damage", Damage)`` and, last,
    ``("orphans", {channel id: count})`` when messages had to be skipped because their
    Channel or Schema record was lost.  Raises :class:`BagError` for an empty file or
    a wrong magic only.
    """

    def __init__(self, src: Source):
        self.src, self.name, self.size = src, src.name, src.size
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.spare_schemas: dict[int, Schema] = {}        # from the summary section
        self.spare_channels: dict[int, Channel] = {}
        self.chunk_indexes: list[ChunkIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        self.statistics: Statistics | None = None
        self.chunked = False
        self.damage: list[Damage] = []
        self.orphans: dict[int, int] = {}
        self.messages = 0                                 # all topics
        self._region: _Region | None = None

    # -- low level ---------------------------------------------------------------------
    def _frame(self, pos: int) -> tuple[int, int] | None:
        head = self.src.read(pos, 9)
        return _HEAD.unpack(head) if len(head) == 9 else None

    def _plausible_next(self, pos: int, opcode: int) -> bool:
        """Does what follows a record ending at ``pos`` look like MCAP?"""
        if opcode == Opcode.FOOTER:
            return self.src.read(pos, 8) == _MAGIC
        if self.size - pos < 9:
            return True             # the file ends there (possibly inside a header)
        op, length = self._frame(pos)
        return (op in _OPCODES or op >= 0x80) and length < 2**32

    def _load_summary(self) -> None:
        """Schemas, channels, chunk indexes and statistics of an intact summary section.

        The footer says where the summary starts; when bytes were inserted or deleted
        before it that offset is wrong, so the section right after the last DataEnd
        record is tried too.  Either must pass the footer's CRC (or, without one,
        parse cleanly up to the footer)."""
        if self.size < 8 + 9 + _FOOTER_LEN + 8:
            return
        footer_at = self.size - _FOOTER_LEN - 8
        tail = self.src.read(footer_at, _FOOTER_LEN + 8)
        if tail[-8:] != _MAGIC or tail[0] != Opcode.FOOTER or \
                _U64.unpack_from(tail, 1)[0] != 20:
            return
        start, _, crc = struct.unpack_from("<QQI", tail, 9)
        if start == 0:
            return                                        # the writer wrote none
        def load(start: int) -> bool:
            data = self.src.read(start, footer_at - start)
            if crc != 0 and zlib.crc32(tail[:9 + 16], zlib.crc32(data)) != crc:
                return False
            return self._parse_summary(data)

        if 8 < start < footer_at and load(start):
            return
        lookback = max(8, footer_at - _SUMMARY_LOOKBACK)
        data_end = self.src.read(lookback, footer_at - lookback).rfind(_DATA_END)
        if data_end >= 0:
            moved = lookback + data_end + len(_DATA_END) + 4
            if moved != start and moved <= footer_at:
                load(moved)

    def _parse_summary(self, data: bytes) -> bool:
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        chunks: list[ChunkIndex] = []
        metadata: list[MetadataIndex] = []
        stats = None
        pos = 0
        try:
            while pos < len(data):
                if pos + 9 > len(data):
                    return False
                opcode, length = _HEAD.unpack_from(data, pos)
                body = data[pos + 9:pos + 9 + length]
                if len(body) != length:
                    return False
                if opcode == Opcode.SCHEMA:
                    record = _parse(Schema, body)
                    schemas[record.id] = record
                elif opcode == Opcode.CHANNEL:
                    record = _parse(Channel, body)
                    channels[record.id] = record
                elif opcode == Opcode.CHUNK_INDEX:
                    chunks.append(_parse(ChunkIndex, body))
                elif opcode == Opcode.STATISTICS:
                    stats = _parse(Statistics, body)
                elif opcode == Opcode.METADATA_INDEX:
                    metadata.append(_parse(MetadataIndex, body))
                elif opcode not in _OPCODES and opcode < 0x80:
                    return False
                pos += 9 + length
        except _Bad:
            return False
        self.spare_schemas, self.spare_channels = schemas, channels
        self.chunk_indexes, self.statistics = chunks, stats
        self.metadata_indexes = metadata
        self.chunked = bool(chunks)
        return True

    def _schema(self, sid: int) -> Schema | None:
        if sid in self.schemas:
            return self.schemas[sid]
        spare = self.spare_schemas.get(sid)
        if spare is not None:
            self.schemas[sid] = spare
        return spare

    def _resolve(self, cid: int) -> tuple[Channel | None, bool]:
        """(channel, whether it was just taken from the summary)."""
        channel = self.channels.get(cid)
        if channel is not None:
            return channel, False
        spare = self.spare_channels.get(cid)
        if spare is None:
            return None, False
        self.channels[cid] = spare
        return spare, True

    # -- records -----------------------------------------------------------------------
    def _read(self, opcode: int, body: bytes, where: int, strict: bool) -> list[tuple]:
        """The events of one top-level record (validated completely before any is used).

        ``strict`` (resynchronizing): the body must parse to its exact length, and a
        Message must belong to a known channel."""
        if opcode == Opcode.CHUNK:
            chunk = _chunk(body)
            self.chunked = True
            return [("chunk", chunk.records, where, chunk.verified)]
        if opcode == Opcode.MESSAGE:
            message = _message(body)
            if strict and message.channel_id not in self.channels and \
                    message.channel_id not in self.spare_channels:
                raise _Bad("message of an unknown channel")
            return [("raw", Opcode.MESSAGE, message, where, False)]
        parsers = {Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.METADATA: Metadata,
                   Opcode.HEADER: Header, Opcode.FOOTER: Footer,
                   Opcode.MESSAGE_INDEX: MessageIndex, Opcode.CHUNK_INDEX: ChunkIndex,
                   Opcode.STATISTICS: Statistics}
        if opcode == Opcode.ATTACHMENT:
            return [("attachment", _attachment(body))]
        cls = parsers.get(opcode)
        if cls is not None:
            return [("raw", opcode, _parse(cls, body, exact=strict), where, False)]
        if opcode in _OPCODES:            # index/summary records without use here
            if strict and opcode == Opcode.DATA_END and len(body) != 4:
                raise _Bad("DataEnd record of the wrong length")
            return [("skip", opcode)]
        return [("private", opcode)]

    def _record_at(self, pos: int, strict: bool) -> tuple[int, int, list[tuple]]:
        """(opcode, end, events) of the record at ``pos``; ``_Bad`` if unreadable."""
        frame = self._frame(pos)
        if frame is None:
            raise _Bad("file ends inside a record header")
        opcode, length = frame
        if length > self.size - pos - 9:
            raise _Bad(f"file ends inside a record of {length} bytes "
                       f"({self.size - pos - 9} left)")
        if opcode not in _OPCODES and opcode < 0x80:
            raise _Bad(f"invalid opcode {opcode:#04x}")
        body = self.src.read(pos + 9, length)
        return opcode, pos + 9 + length, self._read(opcode, body, pos, strict)

    def _excluded(self) -> set[int]:
        """Opcodes a resynchronization must not land on: a Header (first record only)
        and, in a chunked file, the records that live inside chunks (an uncompressed
        chunk holds valid-looking ones that its CRC no longer vouches for)."""
        if self.chunked:
            return {Opcode.HEADER, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE}
        return {Opcode.HEADER}

    def _valid_at(self, p: int) -> bool:
        """Is there a record at ``p`` to resume reading from?  Its body parses exactly
        and the record after it looks like MCAP, or it is a chunk passing its CRC."""
        frame = self._frame(p)
        if frame is None or frame[0] in self._excluded():
            return False
        try:
            opcode, end, events = self._record_at(p, strict=True)
        except _Bad:
            return False
        if events[0][0] == "chunk" and _CHUNK.unpack_from(
                self.src.read(p + 9, _CHUNK.size))[3] != 0:
            return True                                    # its CRC vouches for it
        return self._plausible_next(end, opcode)

    def _resync(self, start: int) -> int | None:
        """Offset of the next valid record at or after ``start`` (``None``: none left)."""
        allowed = np.zeros(256, bool)
        allowed[[o for o in _OPCODES if o not in self._excluded()]] = True
        pos = start
        while pos + 9 <= self.size:
            window = self.src.read(pos, _WINDOW + 8)
            arr = np.frombuffer(window, np.uint8)
            n = len(arr) - 8
            mask = allowed[arr[:n]]
            for k in (5, 6, 7, 8):                          # length < 2**32
                mask &= arr[k:k + n] == 0
            for i in np.flatnonzero(mask):
                if self._valid_at(pos + int(i)):
                    return pos + int(i)
            pos += n
        return None

    # -- damage bookkeeping ------------------------------------------------------------
    def _close_region(self) -> Damage | None:
        region, self._region = self._region, None
        if region is None:
            return None
        lost, times = None, None
        if region.indexed is None and self.chunk_indexes:  # the summary may know
            hit = [c for c in self.chunk_indexes if region.start <= c.chunk_start_offset
                   < region.end]
            if hit:
                times = (min(c.message_start_time for c in hit),
                         max(c.message_end_time for c in hit))
                lost = self._indexed_count(hit)
            else:
                lost = 0        # a chunked file keeps its messages in chunks: none here
        names = tuple(m.name for m in self.metadata_indexes
                      if region.start <= m.offset < region.end)
        damage = region.damage(lost, times, names)
        self.damage.append(damage)
        return damage

    def _indexed_count(self, chunks: list[ChunkIndex]) -> int | None:
        """Messages of these chunks according to their message index records."""
        total = 0
        for c in chunks:
            for offset in c.message_index_offsets.values():
                frame = self._frame(offset)
                if frame is None or frame[0] != Opcode.MESSAGE_INDEX or frame[1] > 2**24:
                    return None
                try:
                    total += len(_parse(MessageIndex, self.src.read(offset + 9, frame[1]))
                                 .records)
                except _Bad:
                    return None
        return total

    def _open_region(self, start: int, end: int, kind: str, reason: str,
                     times: tuple[int, int] | None = None) -> Damage | None:
        closed = self._close_region()
        self._region = _Region(start, end, kind, reason, times)
        return closed

    # -- the loop ----------------------------------------------------------------------
    def events(self) -> Iterator[tuple]:
        magic = self.src.read(0, 8)
        if not magic:
            raise BagError(f"{self.name}: empty file, not an MCAP bag")
        if magic != _MAGIC[:len(magic)]:
            raise BagError(f"{self.name}: not an MCAP file (starts with {magic!r}, expected "
                           f"the MCAP magic {_MAGIC!r})")
        if len(magic) < 8:
            self._open_region(0, self.size, "truncated", "file ends inside the MCAP magic")
            yield ("damage", self._close_region())
            return
        self._load_summary()
        pos, first = 8, True
        # A record is held back until the next one is read: message indexes follow only
        # chunks, so a record they follow was a chunk whose opcode byte got damaged.
        held: tuple[int, int, int, list[tuple]] | None = None

        def flush() -> Iterator[tuple]:
            nonlocal held
            if held is not None:
                record, held = held, None
                yield from self._emit(record[2], record[3])

        def damaged(start: int, end: int, kind: str, reason: str,
                    times: tuple[int, int] | None = None) -> Iterator[tuple]:
            yield from flush()
            closed = self._open_region(start, end, kind, reason, times)
            if closed is not None:
                yield ("damage", closed)

        while True:
            if pos >= self.size:
                yield from damaged(pos, pos, "truncated", "file ends without MCAP footer")
                yield ("damage", self._close_region())
                break
            try:
                opcode, end, events = self._record_at(pos, strict=False)
                if first and opcode != Opcode.HEADER:
                    raise _Bad(f"first record has opcode {opcode:#04x}, expected a Header")
            except _Bad as bad:
                frame = self._frame(pos)
                truncation = bad.reason.startswith("file ends")
                if frame is not None and frame[0] == Opcode.CHUNK:
                    self.chunked = True
                if not truncation and frame is not None and \
                        (frame[0] in _OPCODES or frame[0] >= 0x80) and \
                        self._valid_at(pos + 9 + frame[1]):
                    nxt: int | None = pos + 9 + frame[1]     # the framing holds: skip it
                else:
                    nxt = self._resync(pos + 1)
                first = False
                if nxt is None:
                    yield from damaged(pos, self.size, "truncated" if truncation else
                                       "corrupt", bad.reason, bad.times)
                    yield ("damage", self._close_region())
                    break
                yield from damaged(pos, nxt, "corrupt", bad.reason, bad.times)
                pos = nxt
                continue
            first = False
            kind = events[0][0]
            if kind == "raw" and opcode == Opcode.MESSAGE_INDEX:
                if held is not None and held[3][0][0] != "chunk":
                    start, stop, op = held[:3]
                    held = None                          # its events are dropped
                    yield from damaged(start, stop, "corrupt",
                                       f"a record with opcode {op:#04x} followed by message "
                                       "indexes: a chunk whose opcode byte is damaged")
                yield from flush()
                region = self._region
                if region is not None:
                    index = events[0][2]
                    region.indexed = (region.indexed or 0) + len(index.records)
                    region.index_times += [t for t, _ in index.records]
                pos = end
                continue
            yield from flush()
            if self._region is not None:
                yield ("damage", self._close_region())
            held = (pos, end, opcode, events)
            if opcode == Opcode.FOOTER:
                yield from flush()
                tail = self.src.read(end, 8)
                if tail != _MAGIC:
                    self._open_region(end, self.size, "corrupt" if tail else "truncated",
                                      "footer not followed by MCAP magic")
                    yield ("damage", self._close_region())
                break
            pos = end
        yield from flush()
        if self.orphans:
            yield ("orphans", dict(self.orphans))

    def _emit(self, opcode: int, events: list[tuple]) -> Iterator[tuple]:
        for event in events:
            if event[0] == "chunk":
                for op, record in event[1]:
                    yield from self._emit_record(op, record, event[2], event[3])
            elif event[0] == "raw":
                yield from self._emit_record(*event[1:])
            elif event[0] == "attachment":
                yield event

    def _emit_record(self, opcode: int, record: Any, where: int,
                     verified: bool) -> Iterator[tuple]:
        if opcode == Opcode.MESSAGE:
            self.messages += 1
            channel, spare = self._resolve(record.channel_id)
            if channel is None:
                self.orphans[record.channel_id] = self.orphans.get(record.channel_id, 0) + 1
                return
            schema = self._schema(channel.schema_id) if channel.schema_id else None
            if channel.schema_id and schema is None:
                self.orphans[record.channel_id] = self.orphans.get(record.channel_id, 0) + 1
                return
            if spare:
                yield ("channel", channel, schema)
            yield ("message", record, channel, schema, where, verified)
        elif opcode == Opcode.SCHEMA:
            if record.id in self.schemas and self.schemas[record.id] == record:
                return                                   # repeated (summary section)
            self.schemas[record.id] = record
            yield ("schema", record)
        elif opcode == Opcode.CHANNEL:
            if record.id in self.channels and self.channels[record.id] == record:
                return                                   # repeated (summary section)
            self.channels[record.id] = record
            schema = self._schema(record.schema_id) if record.schema_id else None
            yield ("channel", record, schema)
        elif opcode == Opcode.METADATA:
            yield ("metadata", record)
        elif opcode == Opcode.HEADER:
            yield ("header", record)


def scan(source: Any) -> tuple[Scanner, Source]:
    """The damage-tolerant record scanner of ``source`` (for :mod:`.repair`); close the
    source when done."""
    src = Source(source)
    return Scanner(src), src
