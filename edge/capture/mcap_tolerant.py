"""Reading an MCAP file past damage: a corrupted chunk costs that chunk, not the rest.

The mcap package's readers stop at the first bad record (and a corrupted compressed size can
make them raise MemoryError or lz4's RuntimeError). Here the file is walked record by record
over a memory map; every chunk is decoded by the mcap package (`breakup_chunk`, CRC checked)
inside one boundary that catches whatever a damaged chunk raises. After damage — a chunk
that fails to decode, a record header that cannot be right — reading resumes at the next
plausible chunk header found by scanning forward, whether or not the file has a summary
(a scan also finds chunks a damaged length would have skipped). The messages each damaged
chunk held are counted from the MessageIndex records that follow it, where they survive.
Schemas and channels come from the summary when it is readable, so a message whose chunk
is intact still decodes when the chunk that declared its channel is not, or comes later in
the file (chunks out of order). Without a readable summary, a message on a channel not yet
declared waits (up to MAX_WAITING_BYTES) until a later record declares it.
"""

from __future__ import annotations

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
DATA_END = 15
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


def _summary_records(f) -> tuple[dict, dict]:
    from mcap.reader import make_reader

    try:
        summary = make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 - no summary, or a damaged one: chunks declare them too
        summary = None
    finally:
        f.seek(0)
    if summary is None:
        return {}, {}
    return dict(summary.schemas), dict(summary.channels)


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
        schemas, channels = _summary_records(f)
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            yield from _walk(buf, size, report, schemas, channels)
        report.unknown_channel += sum(len(held) for held in report.waiting.values())
        report.waiting.clear()


def _walk(buf, size: int, report: ReadReport, schemas: dict, channels: dict):
    pos, lost = len(MAGIC), None  # lost: the damage the next MessageIndex records count for
    chunks_read: dict[bytes, int] = {}  # digest of a chunk's bytes -> where it was first read
    while pos + 9 <= size:
        opcode, end = buf[pos], pos + 9 + _u64(buf, pos + 1)
        if opcode not in KNOWN_OPCODES or end > size:
            resume = next_chunk(buf, pos + 1, size)
            if resume is None:  # nothing readable after it: a file cut off mid-record
                report.truncated_at = pos
                return
            report.damage.append(lost := Damage(pos, "unreadable record header"))
            pos = resume
            continue
        body = buf[pos + 9:end]
        if opcode == CHUNK:
            digest = hashlib.blake2b(body, digest_size=16).digest()
            if digest in chunks_read:  # a copied chunk: its messages were read already
                report.duplicates.append((pos, chunks_read[digest]))
                pos = end
                continue
            chunks_read[digest] = pos
            try:
                records = _chunk_records(body) if plausible_chunk(buf, pos, size) else None
            except Exception as exc:  # noqa: BLE001 MemoryError, lz4/zstd errors, CRC, lengths
                records, reason = None, f"chunk: {type(exc).__name__}"
            else:
                reason = "chunk: implausible header"
            if records is None:
                report.damage.append(lost := Damage(pos, reason))
                # a chunk whose framing holds is skipped whole (its MessageIndex records then
                # count what it held); otherwise its length cannot be trusted: scan on
                framed = plausible_chunk(buf, pos, size, exact=True)
                pos = end if framed else (next_chunk(buf, pos + 1, size) or size)
                continue
            lost = None
        elif opcode in (SCHEMA, CHANNEL, MESSAGE) or (opcode == MESSAGE_INDEX and lost):
            try:
                record = _record(opcode, body)
            except Exception as exc:  # noqa: BLE001 - a damaged record: resume after it
                report.damage.append(lost := Damage(pos, f"record: {type(exc).__name__}"))
                pos = next_chunk(buf, pos + 1, size) or size
                continue
            records = [record]
            if opcode == MESSAGE_INDEX and lost is not None:
                lost.messages_lost = (lost.messages_lost or 0) + len(record.records)
                records = []
        elif opcode in (DATA_END, FOOTER):
            return  # the summary follows: it was read first
        else:
            records = []
        pos = end
        yield from _messages(records, report, schemas, channels)


def _messages(records, report: ReadReport, schemas: dict, channels: dict):
    from mcap.records import Channel, Message, Schema

    for record in records:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
            for held in report.waiting.pop(record.id, []):
                report.waiting_bytes -= len(held.data)
                yield schemas.get(record.schema_id), record, held
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is not None:
                yield schemas.get(channel.schema_id), channel, record
            elif report.waiting_bytes + len(record.data) <= MAX_WAITING_BYTES:
                report.waiting.setdefault(record.channel_id, []).append(record)
                report.waiting_bytes += len(record.data)
            else:
                report.unknown_channel += 1
