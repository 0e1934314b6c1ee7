"""Damaged bags: the reader skips corrupt chunks and garbage and reads on, a truncated bag
gives the prefix of complete chunks, ``flexarm bag repair`` rewrites what is readable
into a file every official reader opens, and no damage ends in anything but messages
with warnings or one clear BagError line (a seeded fuzz suite, larger with -m slow).

Truths are independent of the reader under test: ``mcap``'s own readers on the intact
file (which chunk holds which messages, in file order), the positions of the damage,
and for the repaired files ``mcap``'s indexed and stream readers and rosbags."""

import dataclasses
import io
import math
import random
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Chunk as McapChunk
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader, breakup_chunk

from flexarm_ros.bag import (BagError, BagWriter, CorruptChunkWarning, TruncatedBagWarning,
                             iter_messages, read_bag, to_dict)
from flexarm_ros.bag import messages as m
from flexarm_ros.bag.reader import scan
from flexarm_ros.bag.repair import REPAIR_METADATA_NAME, default_output, repair
from flexarm_ros.twin import recording

try:
    from rosbags.highlevel import AnyReader
except ImportError:  # pragma: no cover
    AnyReader = None

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "bags" / "golden_case1.mcap"
needs_rosbags = pytest.mark.skipif(AnyReader is None, reason="rosbags is not installed")


# ------------------------------------------------------------------------------ truths

def mcap_chunks(data: bytes) -> list[tuple]:
    """The intact file's chunks, per ``mcap``: [(ChunkIndex, [(topic, log, pub, seq,
    data)])] in file order."""
    summary = make_reader(io.BytesIO(data)).get_summary()
    topics = {c.id: c.topic for c in summary.channels.values()}
    chunks = [r for r in StreamReader(io.BytesIO(data), emit_chunks=True).records
              if isinstance(r, McapChunk)]
    assert len(chunks) == len(summary.chunk_indexes)
    out = []
    for index, chunk in zip(summary.chunk_indexes, chunks):
        out.append((index, [(topics[r.channel_id], r.log_time, r.publish_time, r.sequence,
                             r.data) for r in breakup_chunk(chunk, validate_crc=True)
                            if isinstance(r, McapMessage)]))
    return out


def mcap_messages(f) -> list[tuple]:
    """Every message in file order per ``mcap``'s indexed (seeking) reader."""
    return [(c.topic, mm.log_time, mm.publish_time, mm.sequence, mm.data)
            for _, c, mm in make_reader(f).iter_messages(log_time_order=False)]


def ours(source) -> tuple[list[tuple], list]:
    """(raw messages in file order, the Damage regions) from the project's scanner."""
    sc, src = scan(source)
    out, damage = [], []
    try:
        for ev in sc.events():
            if ev[0] == "message":
                mm = ev[1]
                out.append((ev[2].topic, mm.log_time, mm.publish_time, mm.sequence, mm.data))
            elif ev[0] == "damage":
                damage.append(ev[1])
    finally:
        src.close()
    return out, damage


def read(source):
    """read_bag with its warnings (any non-damage warning fails the test)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        bag = read_bag(source)
    other = [w for w in caught if not issubclass(w.category, TruncatedBagWarning)]
    assert not other, [str(w.message) for w in other]
    return bag, caught


def flat(bag) -> dict:
    """{topic: [log times]} of a Bag (it keeps file order per topic only)."""
    return {t: [ts for ts, _ in v] for t, v in bag.messages.items() if v}


def by_topic(raw: list[tuple]) -> dict:
    out = {}
    for topic, log, *_ in raw:
        out.setdefault(topic, []).append(log)
    return out


def plain(value):
    if dataclasses.is_dataclass(value):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                if not f.name.startswith("__")}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def same(a, b):
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a):
        return math.isnan(b)
    return a == b


#: messages in the golden bag: 30,008 topics' messages of the 2.5 s lockstep run plus 76
#: arm_markers arrays (30 Hz, since issue 38; the bag was regenerated for issue 40)
GOLDEN_MESSAGES = 30084


@pytest.fixture(scope="module")
def golden():
    data = GOLDEN.read_bytes()
    return data, mcap_chunks(data)


# -------------------------------------------------------------------- corrupt chunks

@pytest.mark.heavy
def test_flipped_byte_in_the_middle_chunk_loses_that_chunk_only(golden, tmp_path):
    """One flipped byte in the middle chunk's compressed data of the golden bag: every
    message outside that chunk is read (count = total − that chunk's count, the same
    bytes in the same order as mcap reads them from the intact file) and one
    CorruptChunkWarning names the chunk's byte range, its message count and log times."""
    data, chunks = golden
    k = len(chunks) // 2
    index, lost = chunks[k]
    assert len(lost) > 100
    bad = bytearray(data)
    bad[index.chunk_start_offset + index.chunk_length // 2] ^= 0xFF
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(bad))
    want = [msg for i, (_, msgs) in enumerate(chunks) if i != k for msg in msgs]
    total = sum(len(msgs) for _, msgs in chunks)
    assert total == GOLDEN_MESSAGES and len(want) == total - len(lost)
    assert ours(path)[0] == want
    bag, caught = read(path)
    assert [w.category for w in caught] == [CorruptChunkWarning]
    text = str(caught[0].message)
    start, end = index.chunk_start_offset, index.chunk_start_offset + index.chunk_length
    assert f"damaged at byte {start} of {len(data)}: skipped bytes {start}–{end}" in text
    t0, t1 = min(m[1] for m in lost), max(m[1] for m in lost)
    assert f": {len(lost)} messages lost (log time {t0 / 1e9:g}–{t1 / 1e9:g} s)" in text
    assert flat(bag) == by_topic(want) and bag.message_count == len(want)
    assert [(d.start, d.end, d.kind, d.lost_messages, d.lost_time_ns) for d in bag.damage] \
        == [(start, end, "corrupt", len(lost), (t0, t1))]
    assert bag.summary_message_count == total and bag.truncated
    assert recording.twin_info(bag)["scene"] == "two_link_case1"


@pytest.mark.heavy
def test_garbage_after_the_header_is_scanned_past(golden, tmp_path):
    """Random bytes over offsets 40–400 (the header record and the start of the twin's
    metadata): the reader finds the next valid record and reads every message mcap's
    indexed reader reads from the damaged file (it seeks through the intact summary);
    the lost Metadata record is named, and the twin's info survives in the rosbag2
    record's custom_data copy."""
    data, chunks = golden
    rnd = random.Random(40400)
    bad = bytearray(data)
    bad[40:400] = bytes(rnd.randrange(256) for _ in range(360))
    path = tmp_path / "garbage.mcap"
    path.write_bytes(bytes(bad))
    with open(path, "rb") as f:
        theirs = mcap_messages(f)
    assert len(theirs) == GOLDEN_MESSAGES
    assert ours(path)[0] == theirs
    bag, caught = read(path)
    assert [w.category for w in caught] == [CorruptChunkWarning]
    assert "damaged at byte 8 of" in str(caught[0].message)
    assert "0 messages lost; Metadata record 'flexarm_ros' lost" in str(caught[0].message)
    assert bag.message_count == GOLDEN_MESSAGES and "flexarm_ros" not in bag.metadata
    assert "model" in bag.metadata                       # the record after the garbage
    assert recording.twin_info(bag)["scene"] == "two_link_case1"
    assert recording.embedded_scene(bag).name == "two_link_case1"


def test_truncations_give_the_complete_chunks_before_the_cut(golden):
    """Cut at 8 seeded offsets (inside chunks, indexes, the summary): exactly the
    messages of the chunks that end before the cut, in order, and a
    TruncatedBagWarning, never another exception."""
    data, chunks = golden
    rnd = random.Random(7)
    cuts = sorted(rnd.randrange(9, len(data)) for _ in range(8))
    for cut in cuts:
        want = [msg for index, msgs in chunks
                if index.chunk_start_offset + index.chunk_length <= cut for msg in msgs]
        got, damage = ours(data[:cut])
        assert got == want, cut
        assert damage and damage[-1].kind == "truncated" and damage[-1].end == cut, cut
    # the public API on one of them: decoded clock values are the prefix's
    cut = cuts[len(cuts) // 2]
    with pytest.warns(TruncatedBagWarning, match=f"truncated at byte .* of {cut} .*recovered"):
        clocks = [mm.log_time_ns for mm in iter_messages(data[:cut], "/clock")]
    assert clocks == [msg[1] for index, msgs in chunks
                      if index.chunk_start_offset + index.chunk_length <= cut
                      for msg in msgs if msg[0] == "/clock"]


def test_a_file_of_random_bytes_is_a_bag_error(tmp_path):
    rnd = random.Random(3)
    path = tmp_path / "noise.mcap"
    path.write_bytes(bytes(rnd.randrange(256) for _ in range(4096)))
    with pytest.raises(BagError, match=f"{path}: not an MCAP file"):
        read_bag(path)
    # behind a valid magic the noise is unreadable damage, not an exception
    path.write_bytes(b"\x89MCAP0\r\n" + path.read_bytes())
    bag, caught = read(path)
    assert bag.message_count == 0 and bag.damage and caught


@pytest.mark.parametrize("command", [
    ["compare", "{bag}", str(GOLDEN)],
    ["replay", "{bag}", "--rerun", "{tmp}/view.rrd"],
    ["bag", "repair", "{bag}"],
])
def test_cli_commands_on_random_bytes_exit_2_with_one_line(tmp_path, capsys, command):
    from flexarm_ros.cli import main
    path = tmp_path / "noise.mcap"
    path.write_bytes(bytes(random.Random(5).randrange(256) for _ in range(2048)))
    argv = [a.format(bag=path, tmp=tmp_path) for a in command]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err and "not an MCAP file" in err, err
    assert str(path) in err


# --------------------------------------------------------------------------- repair

def _readers_agree(path: Path, want: list[tuple], decode: bool = False) -> None:
    """mcap's indexed and stream readers and rosbags read ``want`` from ``path``."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == len(want)
        assert mcap_messages(f) == want
    with open(path, "rb") as f:
        stream = [(c.topic, mm.log_time, mm.publish_time, mm.sequence, mm.data) for _, c, mm
                  in NonSeekingReader(f, validate_crcs=True).iter_messages(
                      log_time_order=False)]     # file order (the recorder's drains need not
                                                 # write in log-time order)
    assert stream == want
    if AnyReader is not None:
        with AnyReader([path]) as rb:
            assert rb.message_count == len(want)
            got = [(c.topic, t) for c, t, _ in rb.messages()]
            assert sorted(got) == sorted((w[0], w[1]) for w in want)
            if decode:
                ours_bag = read_bag(path)
                values = {t: [to_dict(v) for _, v in msgs] for t, msgs in
                          ours_bag.messages.items()}
                theirs = {}
                for c, _, raw in rb.messages():
                    theirs.setdefault(c.topic, []).append(plain(rb.deserialize(raw,
                                                                               c.msgtype)))
                assert values.keys() >= theirs.keys()
                for topic, vals in theirs.items():
                    assert same(values[topic], vals), topic


@pytest.mark.heavy
@needs_rosbags
def test_repair_of_a_corrupt_golden_bag_is_read_by_every_reader(golden, tmp_path, capsys):
    from flexarm_ros.cli import main
    data, chunks = golden
    k = len(chunks) // 2
    index, lost = chunks[k]
    bad = bytearray(data)
    bad[index.chunk_start_offset + index.chunk_length // 2] ^= 0xFF
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(bad))
    assert main(["bag", "repair", str(path)]) == 0
    out = capsys.readouterr().out
    fixed = default_output(path)
    assert fixed == tmp_path / "flipped.repaired.mcap"
    assert out.count("\n") == 1 and out.startswith(
        f"{path}: recovered {GOLDEN_MESSAGES - len(lost)} of {GOLDEN_MESSAGES} messages")
    assert f"{len(lost)} messages lost" in out and out.strip().endswith(f"→ {fixed}")
    assert path.read_bytes() == bytes(bad)                # the input is left as it was
    want = [msg for i, (_, msgs) in enumerate(chunks) if i != k for msg in msgs]
    _readers_agree(fixed, want)
    bag, caught = read(fixed)
    assert not caught and not bag.damage
    original = read_bag(GOLDEN)
    assert bag.types == original.types and bag.profile == original.profile == "ros2"
    for name in ("flexarm_ros", "model"):
        assert bag.metadata[name] == original.metadata[name]
    meta = bag.rosbag2_metadata()
    assert meta["message_count"] == len(want)
    assert {t["topic_metadata"]["name"]: t["message_count"]
            for t in meta["topics_with_message_count"]} == {
        t: len(v) for t, v in by_topic(want).items()}
    old = original.rosbag2_metadata()
    assert meta["custom_data"] == old["custom_data"] and meta["version"] == old["version"]
    assert [t["topic_metadata"] for t in meta["topics_with_message_count"]] == \
        [t["topic_metadata"] for t in old["topics_with_message_count"]]
    assert f"{len(lost)} messages lost" in bag.metadata[REPAIR_METADATA_NAME]["lost"]


_WRITER = """
import sys, time
from flexarm_ros.bag import BagWriter, messages as m
w = BagWriter(sys.argv[1], {"scene": "killed"}, chunk_size=4096)
w.add_metadata("model", {"explain": "a killed writer"})
i = 0
while True:
    t = i * 1_000_000
    w.write("/clock", "rosgraph_msgs/msg/Clock", m.clock(t), t, publish_time_ns=t + 5)
    w.write("/joint_states", "sensor_msgs/msg/JointState",
            m.joint_state(t, ["a", "b"], [0.001 * i, -0.002 * i], [1.0, 2.0]), t, t + 7)
    i += 1
    if i % 50 == 0:
        time.sleep(0.01)
"""


@pytest.mark.subprocess
@needs_rosbags
def test_repair_of_a_sigkilled_writer_is_read_by_every_reader(tmp_path):
    """A real writer process killed by SIGKILL mid-run: no summary, no footer, mcap's
    indexed reader refuses it; after repair the three readers read exactly the
    messages the project's reader recovers from the killed file, with equal decoded
    values."""
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(path)])
    try:
        t0 = time.monotonic()
        while not (path.exists() and path.stat().st_size > 60_000):
            assert proc.poll() is None and time.monotonic() - t0 < 60
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    with open(path, "rb") as f, pytest.raises(Exception):
        make_reader(f).get_summary()                     # why repair exists
    prefix, damage = ours(path)
    assert len(prefix) > 100 and [d.kind for d in damage] == ["truncated"]
    report = repair(path, tmp_path / "fixed.mcap")
    assert report.messages == len(prefix) and report.damage[-1].kind == "truncated"
    _readers_agree(tmp_path / "fixed.mcap", prefix, decode=True)
    fixed = read_bag(tmp_path / "fixed.mcap")
    assert fixed.metadata["flexarm_ros"] == {"scene": "killed"}
    assert fixed.rosbag2_metadata()["custom_data"] == {"scene": "killed"}


@needs_rosbags
def test_repair_of_truncations_inside_chunks(tmp_path):
    """A finalized small bag cut at offsets inside 4 different chunks: each repaired file
    is read by every reader with the messages the project's reader recovers (the
    complete chunks before the cut, per mcap on the intact file)."""
    data = _small_bag()
    chunks = mcap_chunks(data)
    rnd = random.Random(11)
    for k, (index, _) in enumerate(rnd.sample(chunks[1:-1], 4)):
        cut = index.chunk_start_offset + rnd.randrange(10, index.chunk_length)
        want = [msg for c, msgs in chunks
                if c.chunk_start_offset + c.chunk_length <= cut for msg in msgs]
        src = tmp_path / f"cut{cut}.mcap"
        src.write_bytes(data[:cut])
        assert ours(src)[0] == want
        report = repair(src)
        assert report.messages == len(want)
        _readers_agree(default_output(src), want, decode=k == 0)


def test_repair_refuses_to_overwrite_its_input_and_keeps_an_old_output(tmp_path, capsys):
    from flexarm_ros.cli import main
    src = tmp_path / "a.mcap"
    src.write_bytes(_small_bag()[:5000])
    assert main(["bag", "repair", str(src), "--out", str(src)]) == 2
    assert "must differ from the input" in capsys.readouterr().err
    assert main(["bag", "repair", str(tmp_path / "none.mcap")]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    out = tmp_path / "b.mcap"
    out.write_bytes(b"old")
    (tmp_path / "noise.mcap").write_bytes(b"not a bag at all")
    assert main(["bag", "repair", str(tmp_path / "noise.mcap"), "--out", str(out)]) == 2
    assert out.read_bytes() == b"old"                    # nothing half-written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap", "b.mcap", "noise.mcap"]


# ----------------------------------------------------------------------------- fuzz

def _small_bag(compression: str = "zstd") -> bytes:
    buf = io.BytesIO()
    with BagWriter(buf, {"scene": "fuzz"}, chunk_size=2048, compression=compression) as w:
        w.add_metadata("model", {"explain": "text " * 20})
        for i in range(150):
            t = i * 1_000_000
            w.write("/clock", "rosgraph_msgs/msg/Clock", m.clock(t), t)
            w.write("/joint_states", "sensor_msgs/msg/JointState",
                    m.joint_state(t, ["a", "b"], [i * 0.1, -i * 0.2], [1.0, 2.0]), t)
    return buf.getvalue()


def _damage(data: bytes, rnd: random.Random) -> tuple[str, bytes]:
    b = bytearray(data)
    kind = rnd.choice(["truncate", "flip", "insert", "delete", "zero", "garbage"])
    p = rnd.randrange(len(b))
    if kind == "truncate":
        del b[p:]
    elif kind == "flip":
        for _ in range(rnd.randint(1, 3)):
            b[rnd.randrange(len(b))] ^= rnd.randrange(1, 256)
    elif kind == "insert":
        b[p:p] = bytes(rnd.randrange(256) for _ in range(rnd.randint(1, 64)))
    elif kind == "delete":
        del b[p:p + rnd.randint(1, 64)]
    else:
        n = len(b[p:p + rnd.randint(1, 2000)])
        b[p:p + n] = bytes(n) if kind == "zero" else bytes(rnd.randrange(256) for _ in
                                                             range(n))
    return kind, bytes(b)


def _subsequence(part: list, whole: list) -> bool:
    it = iter(whole)
    return all(any(x == y for y in it) for x in part)


def _fuzz(n: int, seed: int, tmp_path: Path, limit_s: float) -> dict:
    """Damage a small CRC-protected bag ``n`` times: each read ends within ``limit_s``
    with messages (an ordered subsequence of the originals, decoded equal; fewer only
    with a warning) or a BagError; each repair gives a file mcap's indexed reader reads
    with the same messages."""
    outcomes = {}
    originals = {c: _small_bag(c) for c in ("zstd", "none")}
    full = {c: ours(d)[0] for c, d in originals.items()}
    rnd = random.Random(seed)
    for i in range(n):
        compression = "zstd" if i % 2 == 0 else "none"
        kind, data = _damage(originals[compression], rnd)
        t0 = time.monotonic()
        try:
            bag, caught = read(data)
        except BagError as err:
            outcomes[(kind, "BagError")] = outcomes.get((kind, "BagError"), 0) + 1
            assert str(err).startswith("<bytes>: ") and "\n" not in str(err)
            continue
        assert time.monotonic() - t0 < limit_s, (i, kind)
        got, _ = ours(data)
        assert _subsequence(got, full[compression]), (i, kind)
        assert bag.message_count == len(got), (i, kind)
        if len(got) < len(full[compression]):
            assert caught, (i, kind)                     # never a silent loss
        state = "complete" if len(got) == len(full[compression]) else "partial"
        outcomes[(kind, state)] = outcomes.get((kind, state), 0) + 1
        src = tmp_path / f"v{i}.mcap"
        src.write_bytes(data)
        report = repair(src, tmp_path / "fixed.mcap")
        assert report.messages == len(got), (i, kind)
        with open(tmp_path / "fixed.mcap", "rb") as f:
            assert mcap_messages(f) == got, (i, kind)
    return outcomes


@pytest.mark.heavy
def test_bag_fuzz_small(tmp_path):
    """50 seeded damaged variants (truncations, flipped bytes, inserted/deleted bytes,
    zeroed and garbage ranges) of a zstd and an uncompressed bag."""
    outcomes = _fuzz(50, 2024, tmp_path, limit_s=5.0)
    assert sum(outcomes.values()) == 50
    assert {k for k, _ in outcomes} == {"truncate", "flip", "insert", "delete", "zero",
                                        "garbage"}


@pytest.mark.slow
def test_bag_fuzz_large(tmp_path):
    outcomes = _fuzz(1000, 99, tmp_path, limit_s=5.0)
    assert sum(outcomes.values()) == 1000


def _unchunked_bag() -> bytes:
    """A foreign layout: messages outside chunks, no CRC anywhere."""
    from mcap.writer import Writer

    from flexarm_ros.bag.msgdefs import full_text
    from flexarm_ros.bag.writer import encode_cdr
    buf = io.BytesIO()
    w = Writer(buf, use_chunking=False)
    w.start(profile="ros2")
    ids = {}
    for tp in ("rosgraph_msgs/msg/Clock", "sensor_msgs/msg/JointState"):
        sid = w.register_schema(tp, "ros2msg", full_text(tp).encode())
        ids[tp] = w.register_channel("/" + tp.rsplit("/", 1)[-1].lower(), "cdr", sid)
    for i in range(150):
        t = i * 1_000_000
        w.add_message(ids["rosgraph_msgs/msg/Clock"], t,
                      encode_cdr("rosgraph_msgs/msg/Clock", m.clock(t)), t)
        w.add_message(ids["sensor_msgs/msg/JointState"], t, encode_cdr(
            "sensor_msgs/msg/JointState", m.joint_state(t, ["a", "b"], [0.1 * i, 0.2], [1.0, 2.0])),
            t)
    w.finish()
    return buf.getvalue()


@pytest.mark.parametrize("n", [pytest.param(30, id="fast"),
                               pytest.param(600, id="slow", marks=pytest.mark.slow)])
def test_bag_fuzz_unchunked_foreign_layout(n):
    """No CRC protects these bytes, so values may come back wrong; what must hold is
    that every read ends with messages and warnings or a BagError, never another
    exception, and quickly."""
    data = _unchunked_bag()
    rnd = random.Random(n)
    for i in range(n):
        kind, damaged = _damage(data, rnd)
        t0 = time.monotonic()
        try:
            read(damaged)
        except BagError:
            pass
        assert time.monotonic() - t0 < 5.0, (i, kind)


# ----------------------------------------------------------- the commands on damage

def _flexarm(*args, cwd):
    exe = Path(sys.executable).with_name("flexarm")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "flexarm_ros.cli"]
    return subprocess.run(cmd + list(args), capture_output=True, text=True, cwd=cwd,
                          timeout=300)


@pytest.mark.heavy
@pytest.mark.subprocess
@pytest.mark.parametrize("damage", ["flip", pytest.param("cut", marks=pytest.mark.slow),
                                    pytest.param("garbage", marks=pytest.mark.slow)])
def test_compare_and_replay_on_damaged_bags_never_trace_back(golden, tmp_path, damage):
    """`flexarm compare` and `flexarm replay --rerun` on damaged golden bags: exit 0, 1 or
    2, each warning and error on one line, no traceback."""
    data, chunks = golden
    bad = bytearray(data)
    if damage == "flip":
        index = chunks[len(chunks) // 3][0]
        bad[index.chunk_start_offset + 100] ^= 0x5A
    elif damage == "cut":
        del bad[len(bad) * 3 // 5:]
    else:
        bad[40:400] = bytes(random.Random(1).randrange(256) for _ in range(360))
    path = tmp_path / f"{damage}.mcap"
    path.write_bytes(bytes(bad))
    for args in (["compare", str(path), str(GOLDEN)],
                 ["replay", str(path), "--rerun", str(tmp_path / "v.rrd"), "--quiet"]):
        r = _flexarm(*args, cwd=tmp_path)
        assert r.returncode in (0, 1, 2), r.stderr
        assert "Traceback" not in r.stderr + r.stdout
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert lines and all(ln.startswith(("flexarm compare: warning:",
                                            "flexarm replay: warning:", "flexarm:",
                                            "flexarm compare:", "flexarm replay:"))
                             for ln in lines), r.stderr
        assert any("MCAP bag is" in ln for ln in lines)
