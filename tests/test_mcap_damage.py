"""A damaged MCAP file costs the damaged chunk, not the rest: each damage kind,
a mutation fuzz of the reader, and replay past a bad chunk of one of our recordings."""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest

from edge_depth.capture.mcap_tolerant import ReadReport, iter_messages

N = 12


def write_file(path, compression: str = "lz4") -> list[int]:
    """N messages, one per chunk (a tiny chunk size); returns each chunk's start offset."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    rng = np.random.default_rng(0)
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=64, compression=CompressionType[compression.upper()])
        w.start()
        channel = w.register_channel("/data", "json", w.register_schema("s", "jsonschema",
                                                                         b"{}"))
        for i in range(N):
            payload = bytes(rng.integers(0, 256, 300, dtype=np.uint8)) + bytes(300)
            w.add_message(channel, log_time=i, data=payload, publish_time=i, sequence=i)
        w.finish()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return [(c.chunk_start_offset, c) for c in summary.chunk_indexes]


def read_all(path) -> tuple[list[int], ReadReport]:
    report = ReadReport()
    return [m.sequence for _, _, m in iter_messages(path, report)], report


def damage(path, offset: int, data: bytes) -> None:
    raw = bytearray(path.read_bytes())
    raw[offset:offset + len(data)] = data
    path.write_bytes(bytes(raw))


@pytest.mark.parametrize("compression", ["lz4", "zstd", "none"])
@pytest.mark.parametrize("kind", ["crc", "compressed size", "chunk length",
                                  "message index length", "payload bit"])
def test_each_damage_kind_costs_only_its_chunk(tmp_path, compression, kind):
    path = tmp_path / "f.mcap"
    chunks = write_file(path, compression)
    assert len(chunks) == N
    k = 3
    start, index = chunks[k]
    body = start + 9
    if kind == "crc":  # the stored CRC of the uncompressed records
        damage(path, body + 24, b"\xde\xad\xbe\xef")
    elif kind == "compressed size":  # claims 4 EiB: used to raise MemoryError
        damage(path, body + 16, struct.pack("<Q", 1 << 62))
    elif kind == "chunk length":
        damage(path, start + 1, struct.pack("<Q", 1 << 50))
    elif kind == "message index length":
        (offset,) = index.message_index_offsets.values()
        damage(path, offset + 1, struct.pack("<Q", 1 << 50))
    else:  # a bit flipped in the middle of the chunk's data
        raw = path.read_bytes()
        middle = start + index.chunk_length // 2
        damage(path, middle, bytes([raw[middle] ^ 0x10]))
    got, report = read_all(path)
    # a length field is not data: the chunk is read by its own fields, nothing is lost
    costs_nothing = kind in ("message index length", "chunk length")
    expected = [i for i in range(N) if i != k or costs_nothing]
    assert got == expected
    assert len(report.damage) == 1 and report.truncated_at is None
    if kind != "message index length":
        assert report.damage[0].offset == start
    if kind == "chunk length":
        assert report.damage[0].messages_lost == 0
    if kind in ("crc", "compressed size", "payload bit"):  # framing intact: the index after
        assert report.damage[0].messages_lost == 1     # the chunk says what it held


@pytest.mark.parametrize("with_summary", [True, False])
def test_a_doubled_chunk_length_costs_no_intact_chunk(tmp_path, with_summary):
    path = tmp_path / "f.mcap"
    chunks = write_file(path)
    start, index = chunks[0]
    if not with_summary:  # cut before the summary: the chunks alone say where they end
        path.write_bytes(path.read_bytes()[:chunks[-1][0] + chunks[-1][1].chunk_length])
    damage(path, start + 1, struct.pack("<Q", 2 * (index.chunk_length - 9)))
    got, report = read_all(path)
    assert got == list(range(N))  # it used to land inside the third chunk and lose two
    assert [d.offset for d in report.damage] == [start]
    assert report.damage[0].messages_lost == 0


@pytest.mark.parametrize("with_summary", [True, False])
def test_a_damaged_records_length_that_still_decodes_costs_at_most_its_own_chunk(
        tmp_path, with_summary):
    path = tmp_path / "f.mcap"
    chunks = write_file(path, "lz4")
    start, index = chunks[3]
    data = start + 9 + 28 + 4 + 3  # the records length field, after "lz4"
    far = chunks[6][0] - (data + 8)  # as if the records ran to chunk 6 (lz4 ignores the rest)
    damage(path, data, struct.pack("<Q", far))
    if not with_summary:
        path.write_bytes(path.read_bytes()[:chunks[-1][0] + chunks[-1][1].chunk_length])
    got, report = read_all(path)
    assert set(range(N)) - set(got) <= {3}  # chunks 4 and 5 are read, not skipped
    assert [i for i in got if i != 3] == [i for i in range(N) if i != 3]


def test_a_message_index_length_running_over_the_next_chunk_costs_nothing(tmp_path):
    path = tmp_path / "f.mcap"
    chunks = write_file(path)
    _, index = chunks[2]
    (offset,) = index.message_index_offsets.values()
    next_start = chunks[3][0]
    damage(path, offset + 1, struct.pack("<Q", next_start - offset + 20))  # inside chunk 3
    got, report = read_all(path)
    assert got == list(range(N))
    assert [d.offset for d in report.damage] == [offset]


def test_chunks_cut_out_of_a_file_are_counted_against_the_summary(tmp_path):
    path = tmp_path / "f.mcap"
    chunks = write_file(path)
    raw = path.read_bytes()
    start, end = chunks[4][0], chunks[6][0]  # chunks 4 and 5 and their message indexes
    path.write_bytes(raw[:start] + raw[end:])  # the summary's offsets now point amiss
    got, report = read_all(path)
    assert got == [i for i in range(N) if i not in (4, 5)]
    assert report.summary_messages == N and report.unaccounted() == 2


def test_a_cut_off_file_reads_its_complete_chunks_and_says_where_it_ends(tmp_path):
    path = tmp_path / "f.mcap"
    chunks = write_file(path)
    start, _ = chunks[7]
    path.write_bytes(path.read_bytes()[:start + 40])  # inside chunk 7
    got, report = read_all(path)
    assert got == list(range(7)) and report.truncated_at == start and not report.damage


def test_not_mcap_at_all_is_a_value_error(tmp_path):
    path = tmp_path / "f.mcap"
    path.write_bytes(b"PK\x03\x04 a zip file, say" * 20)
    with pytest.raises(ValueError, match="not an MCAP file"):
        read_all(path)


def test_mutation_fuzz_never_raises_and_never_hangs(tmp_path):
    """300 mutated files (bit flips, overwritten and zeroed byte ranges, cuts): the reader
    returns each time, with only messages the file held, in order."""
    path = tmp_path / "f.mcap"
    write_file(path)
    clean = path.read_bytes()
    rng = np.random.default_rng(17)
    started = time.monotonic()
    for case in range(300):
        raw = bytearray(clean)
        kind = case % 4
        at = int(rng.integers(8, len(raw)))
        if kind == 0:
            for _ in range(int(rng.integers(1, 8))):
                bit = int(rng.integers(8, len(raw)))
                raw[bit] ^= 1 << int(rng.integers(0, 8))
        elif kind == 1:
            n = int(rng.integers(1, 64))
            raw[at:at + n] = bytes(rng.integers(0, 256, n, dtype=np.uint8))[:len(raw) - at]
        elif kind == 2:
            raw[at:at + 32] = bytes(min(32, len(raw) - at))
        else:
            raw = raw[:at]
        path.write_bytes(bytes(raw))
        got, _ = read_all(path)
        assert got == sorted(set(got)) and set(got) <= set(range(N))
    assert time.monotonic() - started < 60


def test_replay_reads_past_a_damaged_chunk_of_our_recording(tmp_path, caplog):
    from mcap.reader import make_reader

    from edge_depth.capture.replay import McapSource
    from edge_depth.cli import main
    from edge_depth.types import StereoFrame

    path = tmp_path / "rec.mcap"
    assert main(["synth", "--mcap", str(path), "--frames", "4", "--seed", "1000000"]) == 0
    frames = [e for e in McapSource(path) if isinstance(e, StereoFrame)]
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) >= 3
    c = chunks[1]
    raw = bytearray(path.read_bytes())
    raw[c.chunk_start_offset + c.chunk_length // 2] ^= 0xFF
    path.write_bytes(bytes(raw))
    source = McapSource(path)
    after = [e for e in source if isinstance(e, StereoFrame)]
    assert 0 < len(after) < len(frames)
    assert after[-1].stamp_ns == frames[-1].stamp_ns  # what follows the damage is there
    (key,) = [k for k in source.stats.errors if k.startswith("damaged data at byte")]
    assert f"byte {c.chunk_start_offset}" in key and "messages lost" in key
    assert "reading on at the next intact chunk" in caplog.text


def test_replay_mutation_fuzz_ends_in_frames_or_one_clear_error(tmp_path):
    """300 mutated copies of a small recording of ours through McapSource: every one ends
    with its frames or a ReplayError (one line), never another exception."""
    from edge_depth.calibration.io import dumps_calibration
    from edge_depth.capture.replay import McapSource, ReplayError
    from edge_depth.mcap_log import RAW_TOPICS, McapLogger
    from edge_depth.sim import RigConfig, make_sample
    from edge_depth.types import StereoFrame

    path = tmp_path / "rec.mcap"  # small chunks, as a long recording has many
    samples = [make_sample(1_000_000 + i, RigConfig(width=96, height=64)) for i in range(6)]
    with McapLogger(path, topics=RAW_TOPICS, chunk_size=4096, calibration_toml=dumps_calibration(
            samples[0].calibration())) as logger:
        for i, s in enumerate(samples):
            logger.log_frame(s.frame(10**9 + i * 10**8, i))
    clean = path.read_bytes()
    rng = np.random.default_rng(5)
    outcomes = {"frames": 0, "error": 0}
    started = time.monotonic()
    for case in range(300):
        raw = bytearray(clean)
        for _ in range(int(rng.integers(1, 4))):
            at = int(rng.integers(8, len(raw)))
            n = int(rng.integers(1, 16)) if case % 2 else 1
            raw[at:at + n] = bytes(rng.integers(0, 256, n, dtype=np.uint8))[:len(raw) - at]
        mutated = tmp_path / f"m{case % 4}.mcap"
        mutated.write_bytes(bytes(raw))
        try:
            frames = [e for e in McapSource(mutated) if isinstance(e, StereoFrame)]
            outcomes["frames"] += 1
            assert len(frames) <= 6
        except ReplayError as exc:
            assert "\n" not in str(exc)
            outcomes["error"] += 1
    assert outcomes["frames"] > 200  # most single-chunk damage leaves frames to replay
    assert time.monotonic() - started < 120


def test_a_corrupt_log_time_past_2_to_the_32_seconds_is_counted_and_replay_goes_on(
        recording, tmp_path):
    """such a time used to end replay in an OverflowError."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from edge_depth.capture.replay import McapSource
    from edge_depth.mcap_log import TOPICS
    from edge_depth.types import LidarScan, StereoFrame

    path = tmp_path / "bad_time.mcap"
    with open(recording, "rb") as src, open(path, "wb") as dst:
        writer = Writer(dst)
        writer.start()
        schemas, channels, bent = {}, {}, False
        for schema, channel, message in make_reader(src).iter_messages():
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                            schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id])
            log_time = message.log_time
            if channel.topic == TOPICS["lidar"] and not bent:
                log_time, bent = 2**33 * 10**9, True  # one scan's time corrupted
            writer.add_message(channels[channel.id], log_time=log_time, data=message.data,
                               publish_time=log_time)
        writer.finish()
    source = McapSource(path)
    events = list(source)
    assert sum(isinstance(e, StereoFrame) for e in events) == 3
    assert sum(isinstance(e, LidarScan) for e in events) == 2  # 3 scans, one skipped
    assert any("out of range" in k for k in source.stats.errors)
    from edge_depth.commands import replay_command
    from edge_depth.runtime.options import EngineOptions

    # no OverflowError
    assert replay_command(path, tmp_path / "out.mcap", EngineOptions(iters=1)) == 0
