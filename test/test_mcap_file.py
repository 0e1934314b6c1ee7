"""The MCAP writer under BagWriter (:mod:`flexarm_ros.bag.mcap_file`) against the ``mcap``
package: the same records as ``mcap.writer.Writer`` writes for the same calls, read back
with CRCs checked, through the summary's indexes and by streaming."""

from __future__ import annotations

import io
import random

import pytest
from mcap.reader import SeekingReader, StreamReader
from mcap.records import (Channel, Chunk, ChunkIndex, Footer, Message, MessageIndex, Metadata,
                          Schema, Statistics)
from mcap.writer import CompressionType, IndexType, Writer

from flexarm_ros.bag.mcap_file import McapFile

CODECS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "": CompressionType.NONE}


def _calls(seed=3, n=3000):
    """Schemas, channels, messages (times out of order within a few ns), metadata."""
    rng = random.Random(seed)
    calls = [("schema", "std_msgs/msg/Float64", "ros2msg", b"float64 data"),
             ("schema", "std_msgs/msg/String", "ros2msg", b"string data"),
             ("channel", "/a", "cdr", 1, {"offered_qos_profiles": "- depth: 10"}),
             ("channel", "/b", "cdr", 2, {}),
             ("metadata", "info", {"scene": "x"})]
    for i in range(n):
        if i == 1000:
            calls.append(("channel", "/c", "cdr", 1, {"k": "v"}))
        ch = rng.choice([1, 2] + ([3] if i > 1000 else []))
        t = 1_000_000 * i + rng.randint(-5, 5) + 10
        data = bytes(rng.getrandbits(8) for _ in range(rng.randint(4, 300)))
        calls.append(("message", ch, t, data, t + 7, i))
        if i == 2000:
            calls.append(("flush",))
            calls.append(("metadata", "mid", {"k": "v" * 50}))
    return calls


def _write(make, calls) -> bytes:
    out = io.BytesIO()
    w = make(out)
    for c in calls:
        if c[0] == "schema":
            w.register_schema(c[1], c[2], c[3])
        elif c[0] == "channel":
            w.register_channel(c[1], c[2], c[3], c[4])
        elif c[0] == "metadata":
            w.add_metadata(c[1], c[2])
        elif c[0] == "flush":
            w.flush()
        else:
            w.add_message(c[1], c[2], c[3], c[4], c[5])
    w.finish()
    return out.getvalue()


def _mcap_writer(codec, chunk):
    def make(out):
        w = Writer(out, chunk_size=chunk, compression=CODECS[codec],
                   index_types=IndexType.ALL, use_chunking=True, use_statistics=True,
                   use_summary_offsets=True, repeat_channels=True, repeat_schemas=True,
                   enable_crcs=True)
        w.start(profile="ros2", library="test")
        return w
    return make


def _ours(codec, chunk):
    return lambda out: McapFile(out, "ros2", "test", chunk_size=chunk, compression=codec)


def _records(data: bytes, kinds) -> list:
    return [r for r in StreamReader(io.BytesIO(data), skip_magic=False,
                                    emit_chunks=False, validate_crcs=True).records
            if isinstance(r, kinds)]


@pytest.mark.parametrize("codec", ["zstd", "lz4", ""])
def test_same_records_as_the_mcap_writer_crcs_checked(codec):
    calls = _calls()
    ours = _write(_ours(codec, 16 * 1024), calls)
    ref = _write(_mcap_writer(codec, 16 * 1024), calls)
    # every message, schema and channel, in file order, with CRCs checked while streaming
    kinds = (Message, Schema, Channel)
    assert _records(ours, kinds) == _records(ref, kinds)
    assert len(_records(ours, (Message,))) == 3000
    # the summary: statistics equal, chunks indexed (ours closes the chunk before a
    # metadata record, so the chunk count may differ by the metadata written mid-run)
    so, sr = SeekingReader(io.BytesIO(ours)).get_summary(), \
        SeekingReader(io.BytesIO(ref)).get_summary()
    a, b = so.statistics, sr.statistics
    for k in ("message_count", "schema_count", "channel_count", "metadata_count",
              "message_start_time", "message_end_time", "channel_message_counts"):
        assert getattr(a, k) == getattr(b, k), k
    assert so.schemas == sr.schemas and so.channels == sr.channels
    assert a.chunk_count == len(so.chunk_indexes) >= 3
    assert [m.name for m in so.metadata_indexes] == [m.name for m in sr.metadata_indexes]
    # the indexed read (chunk indexes → chunks, in log-time order) gives every message
    got = [(c.topic, m.log_time, m.data) for _, c, m in
           SeekingReader(io.BytesIO(ours), validate_crcs=True).iter_messages()]
    want = [(c.topic, m.log_time, m.data) for _, c, m in
            SeekingReader(io.BytesIO(ref), validate_crcs=True).iter_messages()]
    assert got == want and len(got) == 3000
    meta = {m.name: m.metadata for m in SeekingReader(io.BytesIO(ours)).iter_metadata()}
    assert meta == {"info": {"scene": "x"}, "mid": {"k": "v" * 50}}


def _first(data: bytes):
    """The record at the start of ``data``."""
    return next(iter(StreamReader(io.BytesIO(data), skip_magic=True, emit_chunks=True).records))


def test_chunk_and_message_indexes_point_at_their_records():
    """Every chunk index names a Chunk record at its offset whose message indexes list
    each of its messages at its offset inside the uncompressed chunk."""
    data = _write(_ours("zstd", 8 * 1024), _calls(n=1500))
    summary = SeekingReader(io.BytesIO(data)).get_summary()
    seen = 0
    for ci in summary.chunk_indexes:
        chunk = _first(data[ci.chunk_start_offset:ci.chunk_start_offset + ci.chunk_length])
        assert isinstance(chunk, Chunk)
        assert (chunk.message_start_time, chunk.message_end_time) == \
            (ci.message_start_time, ci.message_end_time)
        import zstandard
        raw = zstandard.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
        # the message indexes follow the chunk, back to back, message_index_length long
        import struct
        offs = sorted(ci.message_index_offsets.values())
        assert offs[0] == ci.chunk_start_offset + ci.chunk_length
        ends = [o + 9 + struct.unpack_from("<Q", data, o + 1)[0] for o in offs]
        assert ends[:-1] == offs[1:]
        assert ci.message_index_length == ends[-1] - offs[0]
        for cid, off in ci.message_index_offsets.items():
            idx = _first(data[off:])
            assert isinstance(idx, MessageIndex) and idx.channel_id == cid
            for t, o in idx.records:
                m = _first(raw[o:])
                assert isinstance(m, Message) and m.channel_id == cid and m.log_time == t
                seen += 1
    assert seen == 1500
    footer = [r for r in StreamReader(io.BytesIO(data), skip_magic=False,
                                      validate_crcs=True).records if isinstance(r, Footer)]
    assert footer and footer[0].summary_crc != 0


def test_time_range_covers_the_open_chunk():
    """The (first, last) log time BagWriter writes into the rosbag2 metadata."""
    f = McapFile(io.BytesIO(), "ros2", "test", chunk_size=1024)
    assert f.time_range() == (None, None)
    f.register_channel("/a", "cdr", 0, {})
    times = [50, 10, 99, 30] * 40          # several chunks of 1 KiB
    for i, t in enumerate(times):
        f.add_message(1, t + i, b"x" * 40, t + i, i)
        assert f.time_range() == (min(v + k for k, v in enumerate(times[:i + 1])),
                                  max(v + k for k, v in enumerate(times[:i + 1])))
    f.finish()


def test_an_empty_file_is_valid():
    data = _write(_ours("zstd", 1024), [("metadata", "m", {"a": "b"})])
    s = SeekingReader(io.BytesIO(data)).get_summary()
    assert s.statistics.message_count == 0 and s.statistics.chunk_count == 0
    assert [r.name for r in _records(data, (Metadata,))] == ["m"]
    assert not list(SeekingReader(io.BytesIO(data)).iter_messages())
