"""Reading an MCAP file past damage: a corrupted chunk costs that chunk, not the rest.

The mcap package's readers stop at the first bad record (and a corrupted compressed size can
make them raise MemoryError or lz4's RuntimeError). Here the file is walked record by record
over a memory map; every chunk is decoded by the mcap package (`breakup_chunk`, CRC checked)
inside one boundary that catches whatever a damaged chunk raises. After damage — a chunk
that fails to decode, a record header that cannot be right — reading resumes at the next
plausible chunk header found by scanning forward, whether or not the file has a summary
(a scan also finds chunks a damaged length would have skipped). A chunk whose record length
disagrees with its own framing is read by its framing, and a record whose length runs over
the start of a chunk that the summary's chunk index names ends there: one bad length field
costs at most its own record. Messages the summary's statistics count but no chunk held
(chunks cut out of the file) are counted too (`ReadReport.unaccounted`). The messages each damaged
chunk held are counted from the MessageIndex records that follow it, where they survive.
Schemas and channels come from the summary when it is readable, so a message whose chunk
is intact still decodes when the chunk that declared its channel is not, or comes later in
the file (chunks out of order). Without a readable summary, a message on a channel not yet
declared waits (up to MAX_WAITING_BYTES) until a later record declares it.
"""

from __future__ import annotations

import bisect
import hashlib
import mmap
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from io import BytesIO
from typing import Any

MAGIC = b"\x89MCAP0\r\n"
HEADER_OP, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK, MESSAGE_INDEX = 1, 2, 3, 4, 5, 6, 7
STATISTICS, DATA_END = 11, 15
KNOWN_OPCODES = set(range(1, 16))
COMPRESSIONS = (b"", b"lz4", b"zstd")
MAX_UNCOMPRESSED = 1 << 31  # a chunk claiming more is damaged (and would exhaust memory)
MAX_WAITING_BYTES = 256 << 20  # messages held for a channel declared later in the file


@dataclass
class Damage:
    offset: int
    reason: str
    messages_lost: int | None = None  # from the MessageIndex records after it, if any


@dataclass
class ReadReport:
    damage: list[Damage] = field(default_factory=list)
    truncated_at: int | None = None  # where the file ends inside a record
    unknown_channel: int = 0  # messages whose channel no intact record declares
    waiting: dict = field(default_factory=dict)  # channel id -> messages before its record
    waiting_bytes: int = 0
    duplicates: list[tuple[int, int]] = field(default_factory=list)  # (offset, first's offset)
    summary_messages: int | None = None  # the summary's message count, where it is readable
    messages_read: int = 0

    def unaccounted(self) -> int:
        """Messages the summary counts that were neither read nor counted as lost to
        damage (whole chunks cut out, or damage whose MessageIndex records are gone)."""
        if self.summary_messages is None:
            return 0
        lost = sum(d.messages_lost or 0 for d in self.damage)
        return max(self.summary_messages - self.messages_read - lost - self.unknown_channel, 0)


def _u64(buf, pos: int) -> int:
    return struct.unpack_from("<Q", buf, pos)[0]


def plausible_chunk(buf, pos: int, size: int, exact: bool = False) -> bool:
    """A chunk record could start at `pos`: opcode 6, its length within the file, a known
    compression, start ≤ end time, and the records' length within the record (`exact`:
    ending exactly where the record does, as writers frame it — the framing alone: the
    times and the uncompressed size are not checked then)."""
    head = pos + 9 + 28  # opcode, length; start, end, uncompressed size, crc
    if head + 4 > size or buf[pos] != CHUNK:
        return False
    end = pos + 9 + _u64(buf, pos + 1)
    start_time, end_time, uncompressed = struct.unpack_from("<QQQ", buf, pos + 9)
    (compression_len,) = struct.unpack_from("<I", buf, head)
    implausible = start_time > end_time or uncompressed > MAX_UNCOMPRESSED
    if end > size or compression_len > 4 or (implausible and not exact):
        return False
    data = head + 4 + compression_len
    if bytes(buf[head + 4:data]) not in COMPRESSIONS or data + 8 > end:
        return False
    records_end = data + 8 + _u64(buf, data)
    return records_end == end if exact else records_end <= end


def next_chunk(buf, start: int, size: int) -> int | None:
    pos = buf.find(b"\x06", start)
    while pos != -1:
        if plausible_chunk(buf, pos, size):
            return pos
        pos = buf.find(b"\x06", pos + 1)
    return None


@dataclass
class _Summary:
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    chunk_starts: list[int] = field(default_factory=list)  # sorted offsets
    message_count: int | None = None


def _summary_records(f) -> _Summary:
    from mcap.reader import make_reader

    try:
        summary = make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 - no summary, or a damaged one: chunks declare them too
        summary = None
    finally:
        f.seek(0)
    if summary is None:
        return _Summary()
    count = None if summary.statistics is None else summary.statistics.message_count
    return _Summary(dict(summary.schemas), dict(summary.channels),
                    sorted(c.chunk_start_offset for c in summary.chunk_indexes), count)


def _chunk_records(body) -> list:
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk
    from mcap.stream_reader import breakup_chunk

    chunk = Chunk.read(ReadDataStream(BytesIO(body)))
    return breakup_chunk(chunk, validate_crc=True)


def _record(opcode: int, body):
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Message, MessageIndex, Schema

    stream = ReadDataStream(BytesIO(body))
    if opcode == MESSAGE:
        return Message.read(stream, len(body))
    kinds: dict[int, Any] = {SCHEMA: Schema, CHANNEL: Channel, MESSAGE_INDEX: MessageIndex}
    return kinds[opcode].read(stream)


def iter_messages(path, report: ReadReport) -> Iterator[tuple]:
    """(schema or None, channel, message) of every readable message, in file order; damage
    and a cut-off end go into `report`. ValueError if the file is not MCAP at all."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size < len(MAGIC) or f.read(len(MAGIC)) != MAGIC:
            raise ValueError("not an MCAP file (no MCAP magic at the start)")
        f.seek(0)  # the summary reader locates the footer from the file's start
        summary = _summary_records(f)
        report.summary_messages = summary.message_count
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            yield from _walk(buf, size, report, summary)
        report.unknown_channel += sum(len(held) for held in report.waiting.values())
        report.waiting.clear()


def _framing_end(buf, pos: int, size: int) -> int | None:
    """Where a chunk at `pos` ends by its own fields (compression, records length), whatever
    its record length says; None when those fields cannot be right."""
    head = pos + 9 + 28
    if head + 4 > size or buf[pos] != CHUNK:
        return None
    start_time, end_time, uncompressed = struct.unpack_from("<QQQ", buf, pos + 9)
    (compression_len,) = struct.unpack_from("<I", buf, head)
    data = head + 4 + compression_len
    if (compression_len > 4 or bytes(buf[head + 4:data]) not in COMPRESSIONS
            or data + 8 > size or start_time > end_time or uncompressed > MAX_UNCOMPRESSED):
        return None
    records_end = data + 8 + _u64(buf, data)
    return records_end if records_end <= size else None


def _message_count_after(buf, pos: int, size: int) -> int | None:
    """The Statistics record's message count in the summary section from `pos` on, found
    by walking its records (a file with chunks cut out has a footer that points amiss)."""
    while pos + 9 + 8 <= size and buf[pos] in KNOWN_OPCODES and buf[pos] != FOOTER:
        if buf[pos] == STATISTICS:
            return _u64(buf, pos + 9)
        pos += 9 + _u64(buf, pos + 1)
    return None


def _known_chunk_after(chunk_starts: list[int], pos: int) -> int | None:
    """The first chunk start after `pos` that the summary's chunk index names."""
    i = bisect.bisect_right(chunk_starts, pos)
    return chunk_starts[i] if i < len(chunk_starts) else None


def _walk(buf, size: int, report: ReadReport, summary: _Summary):
    pos, lost = len(MAGIC), None  # lost: the damage the next MessageIndex records count for
    chunks_read: dict[bytes, int] = {}  # digest of a chunk's bytes -> where it was first read
    while pos + 9 <= size:
        opcode, end = buf[pos], pos + 9 + _u64(buf, pos + 1)
        framed = _framing_end(buf, pos, size) if opcode == CHUNK else None
        known = _known_chunk_after(summary.chunk_starts, pos)
        if opcode not in KNOWN_OPCODES or (end > size and framed is None):
            resume = next_chunk(buf, pos + 1, size)
            if resume is None:  # nothing readable after it: a file cut off mid-record
                report.truncated_at = pos
                return
            report.damage.append(lost := Damage(pos, "unreadable record header"))
            pos = resume
            continue
        if opcode != CHUNK and known is not None and end > known:
            report.damage.append(lost := Damage(pos, f"record length runs over the chunk at "
                                                     f"byte {known}"))
            pos = known
            continue
        if opcode == CHUNK:
            records, pos, damage = _read_chunk(buf, pos, end, framed, size, report,
                                               chunks_read, summary.chunk_starts)
            if damage is not None:
                report.damage.append(damage)
            lost = damage if damage is not None and damage.messages_lost is None else None
            yield from _messages(records, report, summary)
            continue
        if opcode in (DATA_END, FOOTER):  # the summary follows: it was read first, or
            if report.summary_messages is None:  # the footer's offsets point amiss
                report.summary_messages = _message_count_after(buf, end, size)
            return
        records = []
        if opcode in (SCHEMA, CHANNEL, MESSAGE) or (opcode == MESSAGE_INDEX and lost):
            try:
                records = [_record(opcode, buf[pos + 9:end])]
            except Exception as exc:  # noqa: BLE001 - a damaged record: resume after it
                report.damage.append(lost := Damage(pos, f"record: {type(exc).__name__}"))
                pos = next_chunk(buf, pos + 1, size) or size
                continue
            if opcode == MESSAGE_INDEX and lost is not None:
                lost.messages_lost = (lost.messages_lost or 0) + len(records[0].records)
                records = []
        pos = end
        yield from _messages(records, report, summary)


def _record_starts(buf, pos: int, size: int) -> bool:
    """Whether a plausible record starts at `pos`: a chunk that frames itself, or a known
    opcode whose length stays inside the file (or `pos` is the file's end)."""
    if pos == size:
        return True
    if pos + 9 > size or buf[pos] not in KNOWN_OPCODES:
        return False
    if buf[pos] == CHUNK:
        return plausible_chunk(buf, pos, size, exact=True)
    return pos + 9 + _u64(buf, pos + 1) <= size


def _trust_framing(buf, pos: int, end: int, framed: int | None, size: int,
                   chunk_starts: list[int]) -> bool:
    """Whether a chunk's own fields, not its record length, say where it ends: they disagree,
    no record starts where the length points, one does where the fields point, and no chunk
    the summary names lies between (a damaged records-length field that still decodes —
    compressors ignore trailing bytes — must not skip the chunks after it)."""
    if framed is None or framed == end or (end <= size and _record_starts(buf, end, size)):
        return False
    known = _known_chunk_after(chunk_starts, pos)
    return _record_starts(buf, framed, size) and (known is None or known >= framed)


def _read_chunk(buf, pos: int, end: int, framed: int | None, size: int, report: ReadReport,
                chunks_read: dict, chunk_starts: list[int]) -> tuple[list, int, Damage | None]:
    """A chunk's records, where reading goes on after it, and its damage (None: intact).
    `end`: where its record length ends it; `framed`: where its own fields do. When only the
    length is damaged (`_trust_framing`) and the chunk decodes by its fields, nothing is
    lost."""
    if _trust_framing(buf, pos, end, framed, size, chunk_starts):
        assert framed is not None
        try:
            records = _chunk_records(buf[pos + 9:framed])
        except Exception:  # noqa: BLE001 - the fields are the damaged part: read as below
            pass
        else:
            return records, framed, Damage(pos, f"chunk: record length {end - pos - 9} where "
                                                f"its own fields say {framed - pos - 9} (read "
                                                "by its fields)", messages_lost=0)
    end = min(end, size)
    body = buf[pos + 9:end]
    digest = hashlib.blake2b(body, digest_size=16).digest()
    if digest in chunks_read:  # a copied chunk: its messages were read already
        report.duplicates.append((pos, chunks_read[digest]))
        return [], end, None
    chunks_read[digest] = pos
    decoded: list | None
    try:
        decoded = _chunk_records(body) if plausible_chunk(buf, pos, size) else None
    except Exception as exc:  # noqa: BLE001 MemoryError, lz4/zstd errors, CRC, lengths
        decoded, reason = None, f"chunk: {type(exc).__name__}"
    else:
        reason = "chunk: implausible header"
    if decoded is not None:
        return decoded, end, None
    # a chunk whose framing holds is skipped whole (its MessageIndex records then count what
    # it held); otherwise its length cannot be trusted: scan on
    exact = plausible_chunk(buf, pos, size, exact=True)
    return [], end if exact else (next_chunk(buf, pos + 1, size) or size), Damage(pos, reason)


def _messages(records, report: ReadReport, summary: _Summary):
    from mcap.records import Channel, Message, Schema

    schemas, channels = summary.schemas, summary.channels
    for record in records:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
            for held in report.waiting.pop(record.id, []):
                report.waiting_bytes -= len(held.data)
                report.messages_read += 1
                yield schemas.get(record.schema_id), record, held
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is not None:
                report.messages_read += 1
                yield schemas.get(channel.schema_id), channel, record
            elif report.waiting_bytes + len(record.data) <= MAX_WAITING_BYTES:
                report.waiting.setdefault(record.channel_id, []).append(record)
                report.waiting_bytes += len(record.data)
            else:
                report.unknown_channel += 1


def _complete_end(buf, size: int) -> int:
    """Where the last complete record of the data section ends: the walk stops at a record
    that runs past the file's end (a writer cut off mid-chunk leaves its length unset), at an
    unknown opcode, at a chunk whose framing does not hold or at the data section's end."""
    pos, last_chunk = len(MAGIC), None
    while pos + 9 <= size:
        opcode, end = buf[pos], pos + 9 + _u64(buf, pos + 1)
        if opcode not in KNOWN_OPCODES or opcode in (DATA_END, FOOTER) or end > size:
            break
        if opcode == CHUNK:
            if not plausible_chunk(buf, pos, size, exact=True):
                break
            last_chunk = pos
        pos = end
    if last_chunk is not None:  # the last chunk's bytes may be the ones a failed write left
        try:
            _chunk_records(buf[last_chunk + 9:last_chunk + 9 + _u64(buf, last_chunk + 1)])
        except Exception:  # noqa: BLE001 - CRC, lengths, compression: cut before it
            return last_chunk
    return pos


def end_cut_file(path) -> int:
    """End an MCAP file whose writer could not finish it (a full disk): cut it after its last
    complete record and append the data section's end and a footer without a summary, which
    every reader takes (the official ones read such a file from start to end). The cut frees
    more than the ~50 bytes appended. Returns the bytes kept before the ending."""
    with open(path, "r+b") as f:
        size = os.fstat(f.fileno()).st_size
        if size < len(MAGIC) + 9:
            end = 0
        else:
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
                end = _complete_end(buf, size) if buf[:len(MAGIC)] == MAGIC else 0
        end = 0 if end <= len(MAGIC) else end  # not even its header: an empty file anew
        f.truncate(end)
        f.seek(end)
        ending = b"" if end else MAGIC + struct.pack("<BQ", HEADER_OP, 8) + bytes(8)
        # DataEnd (CRC 0: not computed), Footer (no summary: starts and CRC 0), magic
        ending += struct.pack("<BQI", DATA_END, 4, 0) + struct.pack("<BQQQI", FOOTER, 20, 0, 0, 0)
        f.write(ending + MAGIC)
    return end
