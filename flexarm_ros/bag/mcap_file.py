"""The MCAP file under :class:`~flexarm_ros.bag.BagWriter`: chunks, indexes and summary,
with a per-message path that costs one ``struct.pack`` and two appends.

Why not ``mcap.writer.Writer`` (which this module replaces for writing; reading stays
with the ``mcap`` package): its ``add_message`` builds a ``Message`` dataclass, updates
statistics and the chunk's index through several attribute lookups, and writes the record
field by field into a ``BytesIO`` with a seek back to patch the length — 16 µs per message
here (60 000 raw 200-byte messages into memory, mcap 1.6), about 12 % of a lockstep tick
of ``two_link_case1`` with the recorder on (12 messages per tick; cProfile, session 7).
This writer appends the 31-byte message header (opcode, length, channel, sequence, log
and publish time; MCAP spec, *Message* record 0x05) and the data to one ``bytearray`` and
the (log time, offset) pair to the channel's index list; what happens per chunk (about
every 256 KiB) and at the end — chunk, message-index, chunk-index, statistics,
summary-offset, data-end and footer records, CRCs — is built from ``mcap.records`` (the
library's own record encoders), with the same layout and options as the ``Writer`` it
replaces was used with: chunked, every index, statistics, summary offsets, schemas and
channels repeated in the summary, CRCs on.

Records in the data section, in order: magic, Header; then per chunk a Chunk record
(holding the schemas and channels registered since the last chunk, then the messages),
one Message Index record per channel in it (encoded here, like the Message records); Metadata records between chunks (a
metadata record closes the chunk being filled first, so the file stays in time order for
a reader that streams it); Data End with the data section's CRC. Summary: schemas,
channels, statistics, chunk indexes, metadata indexes, summary offsets; Footer; magic.
The tests read the files back with ``mcap``'s reader (CRCs checked), ``mcap_ros2`` and
``rosbags`` (``test/test_bag.py``).
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Metadata,
                          MetadataIndex, Schema, Statistics, SummaryOffset)

MAGIC = b"\x89MCAP0\r\n"
_MESSAGE = struct.Struct("<BQHIQQ")     # opcode, record length, channel, sequence, log, publish
_MESSAGE_FIXED = 2 + 4 + 8 + 8          # the record's fields before the data
_INDEX_HEAD = struct.Struct("<BQHI")     # opcode, record length, channel, records' bytes


def message_index(channel_id: int, records: list) -> bytes:
    """A Message Index record (0x07): the channel and its (log time, offset in the
    uncompressed chunk) pairs, u64 each — one ``struct.pack`` for the pairs (mcap's
    ``MessageIndex.write`` packs each number on its own: 4 µs per message)."""
    n = 16 * len(records)
    flat = [v for pair in records for v in pair]
    return (_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 2 + 4 + n, channel_id, n)
            + struct.pack(f"<{2 * len(records)}Q", *flat))


def _compressor(name: str):
    """(name written into the chunk, function) for ``"zstd"``, ``"lz4"`` or ``""``."""
    if name == "zstd":
        import zstandard
        c = zstandard.ZstdCompressor()
        return "zstd", c.compress
    if name == "lz4":
        import lz4.frame
        return "lz4", lz4.frame.compress
    if name == "":
        return "", None
    raise ValueError(f"compression: got {name!r}, expected 'zstd', 'lz4' or ''")


class McapFile:
    """An MCAP file being written to ``stream`` (binary, with ``write`` and ``tell``).

    ``McapFile(stream, profile, library, chunk_size=256 KiB, compression="zstd")``;
    ``register_schema``, ``register_channel``, ``add_message``, ``add_metadata``,
    ``flush`` (closes the chunk being filled), ``finish`` (summary and footer; the stream
    stays open)."""

    def __init__(self, stream, profile: str, library: str, chunk_size: int = 256 * 1024,
                 compression: str = "zstd"):
        self._stream = stream
        self._chunk_size = chunk_size
        self._compression, self._compress = _compressor(compression)
        self._crc = 0                              # data section CRC so far
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk = bytearray()                  # the chunk's records being filled
        self._index: dict[int, list] = {}          # channel → [(log time, offset)] in it
        self._chunk_start = self._chunk_end = None  # its message times
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = defaultdict(int)
        self._n_messages = 0
        self._start = self._end = None             # message times over the file
        self._n_metadata = self._n_chunks = 0
        self._write_data(MAGIC)
        self._write_record(Header(profile, library))

    # ------------------------------------------------------------------ data section
    def _write_data(self, data) -> None:
        self._crc = zlib.crc32(data, self._crc)
        self._stream.write(data)

    def _write_record(self, record) -> int:
        """Write one record (an ``mcap.records`` object) now; its length in bytes."""
        b = RecordBuilder()
        record.write(b)
        data = b.end()
        self._write_data(data)
        return len(data)

    @staticmethod
    def _encode(record) -> bytes:
        b = RecordBuilder()
        record.write(b)
        return b.end()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self._schemas) + 1
        s = Schema(id=sid, name=name, encoding=encoding, data=data)
        self._schemas[sid] = s
        self._chunk += self._encode(s)
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict) -> int:
        cid = len(self._channels) + 1
        c = Channel(id=cid, topic=topic, message_encoding=message_encoding,
                    schema_id=schema_id, metadata=dict(metadata))
        self._channels[cid] = c
        self._chunk += self._encode(c)
        return cid

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int,
                    sequence: int) -> None:
        """Append one Message record to the chunk (closed past ``chunk_size``)."""
        chunk = self._chunk
        idx = self._index.get(channel_id)
        if idx is None:
            idx = self._index[channel_id] = []
        idx.append((log_time, len(chunk)))
        chunk += _MESSAGE.pack(Opcode.MESSAGE, _MESSAGE_FIXED + len(data), channel_id,
                               sequence, log_time, publish_time)
        chunk += data
        self._counts[channel_id] += 1
        if self._chunk_start is None:
            self._chunk_start = self._chunk_end = log_time
        elif log_time < self._chunk_start:
            self._chunk_start = log_time
        elif log_time > self._chunk_end:
            self._chunk_end = log_time
        if len(chunk) > self._chunk_size:
            self._close_chunk()

    def _close_chunk(self) -> None:
        """Write the chunk being filled and its message indexes (nothing without messages:
        its schema and channel records wait for the next one, as mcap's writer does)."""
        if self._chunk_start is None:
            return
        raw = bytes(self._chunk)
        packed = self._compress(raw) if self._compress else raw
        start, end = self._chunk_start, self._chunk_end
        offset = self._stream.tell()
        length = self._write_record(Chunk(
            message_start_time=start, message_end_time=end, uncompressed_size=len(raw),
            uncompressed_crc=zlib.crc32(raw), compression=self._compression, data=packed))
        index_offsets, at = {}, self._stream.tell()
        for cid, records in self._index.items():
            index_offsets[cid] = at
            data = message_index(cid, records)
            self._write_data(data)
            at += len(data)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=start, message_end_time=end, chunk_start_offset=offset,
            chunk_length=length, message_index_offsets=index_offsets,
            message_index_length=at - (offset + length), compression=self._compression,
            compressed_size=len(packed), uncompressed_size=len(raw)))
        self._n_chunks += 1
        n = sum(len(r) for r in self._index.values())
        self._n_messages += n
        self._start = start if self._start is None else min(self._start, start)
        self._end = end if self._end is None else max(self._end, end)
        self._chunk = bytearray()
        self._index = {}
        self._chunk_start = self._chunk_end = None

    def time_range(self) -> tuple:
        """(first, last) log time of the messages written so far, the chunk being filled
        included; (None, None) before any."""
        lo = [v for v in (self._start, self._chunk_start) if v is not None]
        hi = [v for v in (self._end, self._chunk_end) if v is not None]
        return (min(lo), max(hi)) if lo else (None, None)

    def add_metadata(self, name: str, data: dict) -> None:
        """A Metadata record, after the chunk being filled (closed first)."""
        self._close_chunk()
        offset = self._stream.tell()
        length = self._write_record(Metadata(name=name, metadata=dict(data)))
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))
        self._n_metadata += 1

    def flush(self) -> None:
        """Close the chunk being filled (if it holds a message)."""
        self._close_chunk()

    # ----------------------------------------------------------------------- summary
    def finish(self) -> None:
        """The last chunk, Data End, the summary section, the footer and the magic."""
        self._close_chunk()
        self._write_record(DataEnd(data_section_crc=self._crc))
        summary_start = self._stream.tell()
        out = RecordBuilder()
        offsets = []

        def group(opcode, records):
            begin = out.count
            for r in records:
                r.write(out)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + begin,
                                         group_length=out.count - begin))

        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        group(Opcode.STATISTICS, [Statistics(
            message_count=self._n_messages, schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0,
            metadata_count=self._n_metadata, chunk_count=self._n_chunks,
            message_start_time=self._start or 0, message_end_time=self._end or 0,
            channel_message_counts=dict(self._counts))])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        offset_start = summary_start + out.count
        for o in offsets:
            o.write(out)
        summary = out.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start,
                                     offset_start), crc)
        self._stream.write(summary)
        b = RecordBuilder()
        Footer(summary_start=summary_start, summary_offset_start=offset_start,
               summary_crc=crc).write(b)
        self._stream.write(b.end())
        self._stream.write(MAGIC)
