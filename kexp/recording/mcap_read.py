"""Bounded reading of an MCAP file's messages: what a file may make kexp decompress, and so allocate and parse, is
bounded before anything is decompressed, so a handed file cannot hang or exhaust memory.

The MCAP framing (https://mcap.dev/spec): magic, then records (opcode u8, length u64, body) up to the Footer;
schemas, channels and messages either at the top level or inside Chunk records (compressed zstd, lz4 or not at
all, with the CRC-32 of the uncompressed records).  This reader walks the records once, in file order, and yields
every message as (topic, log time, data).  Limits, each checked on the chunk's declared sizes before its data is
read or decompressed (a refusal is a :class:`~kexp.recording.reader.LogError` naming the file and the chunk's
byte offset):

- :data:`CHUNK_LIMIT`, 64 MiB uncompressed per chunk.  kexp's writer closes a chunk once its records pass 1 MiB
  (``chunk_size`` in :mod:`kexp.recording.writer`), so its chunks are 1 MiB plus one message: the largest
  measured was 1 048 654 bytes over a 30 000-step run (302 chunks); 64× that leaves room for one large message.
- :data:`RATIO_LIMIT`: all chunks of a file together may declare at most 64 × the file's size + 1 MiB.  kexp's
  logs decompress to 2.4-3.0× their size (JSON of full-precision floats); the most repetitive measured, a run
  resting exactly at the origin, 5.6× (12× for its most repetitive chunk); 2 GiB of zeros compress 32 000-fold.
  This also bounds the work: a 1.6 KB file makes at most ~1.1 MB to parse.
- :data:`TOTAL_LIMIT`, 4 GiB in all: read_log holds every message in memory.
- Decompression itself is bounded: at most the declared size plus one byte is ever produced, so a chunk whose
  data decompresses past what it declares is refused without expanding further (and the zstd window is at
  most 64 MiB: zstandard refuses a frame that asks for more).

A file that ends inside a record (a killed writer) or whose chunk fails its CRC or does not decode raises
:class:`Cut` (the caller keeps what was read before it and warns); a file past a limit raises LogError.
"""
from __future__ import annotations

import os
import struct
import zlib
from typing import BinaryIO, Iterator

from .mcap_file import CHANNEL, CHUNK, FOOTER, MAGIC, MESSAGE, SCHEMA

CHUNK_LIMIT = 64 << 20       # bytes one chunk may declare uncompressed
RATIO_LIMIT = 64             # uncompressed bytes of all chunks per byte of file (plus RATIO_SLACK)
RATIO_SLACK = 1 << 20
TOTAL_LIMIT = 4 << 30        # uncompressed bytes of all chunks, whatever the file's size

_HEAD = struct.Struct("<BQ")
_CHUNK_FIXED = struct.Struct("<QQQII")   # start, end, uncompressed size, uncompressed CRC, compression length
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_MESSAGE_FIXED = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


class Cut(Exception):
    """The file ends inside a record, or a chunk is corrupt: what was read before it stands."""


def _mib(n: int) -> str:
    return f"{n / (1 << 20):.4g} MiB"


def budget(file_size: int) -> int:
    """Uncompressed bytes all chunks of a file of ``file_size`` bytes may declare together."""
    return min(TOTAL_LIMIT, RATIO_LIMIT * file_size + RATIO_SLACK)


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """At most ``size + 1`` bytes of the chunk's records (one more than declared shows a lie)."""
    if compression == "zstd":
        import zstandard
        dctx = zstandard.ZstdDecompressor(max_window_size=CHUNK_LIMIT)
        parts, got = [], 0
        with dctx.stream_reader(data) as r:
            while got <= size:
                part = r.read(size + 1 - got)
                if not part:
                    break
                parts.append(part)
                got += len(part)
        return b"".join(parts)
    if compression == "lz4":
        import lz4.frame
        return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
    if compression == "":
        return data
    raise Cut(f"unknown compression {compression[:20]!r}")


def _string(buf, at: int, end: int) -> tuple[str, int]:
    if at + 4 > end:
        raise Cut("record too short")
    n = _U32.unpack_from(buf, at)[0]
    if at + 4 + n > end:
        raise Cut("record too short")
    return bytes(buf[at + 4:at + 4 + n]).decode(), at + 4 + n


class _Records:
    """Schemas and channels seen so far; turns Schema/Channel/Message records into (topic, time, data)."""

    def __init__(self):
        self.schemas: set[int] = set()
        self.topics: dict[int, str] = {}

    def take(self, opcode: int, buf, at: int, end: int):
        """The message at buf[at:end] as (topic, log time, data), or None for a schema/channel/other record."""
        if opcode == MESSAGE:
            if end - at < _MESSAGE_FIXED.size:
                raise Cut("message record too short")
            channel, _seq, log_time, _pub = _MESSAGE_FIXED.unpack_from(buf, at)
            topic = self.topics.get(channel)
            if topic is None:
                raise Cut(f"message on unknown channel {channel}")
            return topic, log_time, bytes(buf[at + _MESSAGE_FIXED.size:end])
        if opcode == SCHEMA:
            if end - at < 2:
                raise Cut("schema record too short")
            self.schemas.add(_U16.unpack_from(buf, at)[0])
        elif opcode == CHANNEL:
            if end - at < 4:
                raise Cut("channel record too short")
            channel, schema = struct.unpack_from("<HH", buf, at)
            if schema != 0 and schema not in self.schemas:
                raise Cut(f"channel {channel} names unknown schema {schema}")
            self.topics[channel] = _string(buf, at + 4, end)[0]
        return None


def iter_messages(f: BinaryIO, name: str) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log time ns, data) of every message of the open MCAP file ``f`` (at its start), in file order;
    ``name`` names the file in errors.  Raises :class:`Cut` where the file ends early or a chunk is corrupt,
    LogError past a limit (see the module docstring)."""
    from .reader import LogError
    size = os.fstat(f.fileno()).st_size
    allowed = budget(size)
    if f.read(len(MAGIC)) != MAGIC:
        raise LogError(f"{name} is not an MCAP file (bad magic); pass a run.mcap written by kexp")
    records, pos, declared = _Records(), len(MAGIC), 0
    while True:
        head = f.read(_HEAD.size)
        if len(head) < _HEAD.size:
            raise Cut("the file ends before its footer")
        opcode, length = _HEAD.unpack(head)
        offset, pos = pos, pos + _HEAD.size
        if length > size - pos:
            raise Cut(f"the file ends inside the record at byte {offset}")
        if opcode == FOOTER:
            f.read(length)
            if f.read(len(MAGIC)) != MAGIC:
                raise Cut("no magic after the footer")
            return
        if opcode != CHUNK:
            body = f.read(length)
            pos += length
            if opcode in (MESSAGE, SCHEMA, CHANNEL):
                out = records.take(opcode, body, 0, length)
                if out is not None:
                    yield out
            continue
        fixed = f.read(_CHUNK_FIXED.size)
        if length < _CHUNK_FIXED.size + 8 or len(fixed) < _CHUNK_FIXED.size:
            raise Cut(f"chunk at byte {offset} too short")
        _start, _end, usize, crc, clen = _CHUNK_FIXED.unpack(fixed)
        if _CHUNK_FIXED.size + clen + 8 > length:
            raise Cut(f"chunk at byte {offset} too short")
        compression = f.read(clen).decode(errors="replace")
        dlen = _U64.unpack(f.read(8))[0]
        if usize > CHUNK_LIMIT:
            raise LogError(f"{name}: the chunk at byte {offset} declares {_mib(usize)} uncompressed, past the limit of "
                           f"{_mib(CHUNK_LIMIT)} per chunk (kexp writes chunks of ~1 MiB); refused as a "
                           "decompression bomb or a log kexp did not write")
        declared += usize
        if declared > allowed:
            raise LogError(f"{name}: the chunk at byte {offset} brings the declared uncompressed size to "
                           f"{_mib(declared)}, past this file's budget of {_mib(allowed)} ({RATIO_LIMIT}× its "
                           f"{size} bytes + 1 MiB; kexp's logs decompress to ~3× their size); refused as a "
                           "decompression bomb")
        rest = length - _CHUNK_FIXED.size - clen - 8
        if dlen > rest:
            raise Cut(f"chunk at byte {offset}: its data is longer than the record")
        data = f.read(dlen)
        f.read(rest - dlen)
        pos += length
        try:
            raw = _decompress(compression, data, usize)
        except Cut:
            raise
        except Exception as exc:  # noqa: BLE001 - zstd/lz4 errors of a corrupt chunk
            raise Cut(f"chunk at byte {offset} does not decompress ({type(exc).__name__})") from None
        if len(raw) > usize:
            raise LogError(f"{name}: the chunk at byte {offset} decompresses past the {usize} bytes it declares; "
                           "refused as a decompression bomb or a corrupt log")
        if len(raw) < usize:
            raise Cut(f"chunk at byte {offset} decompresses to {len(raw)} of its {usize} declared bytes")
        if crc and zlib.crc32(raw) != crc:
            raise Cut(f"chunk at byte {offset} fails its CRC")
        buf, at = memoryview(raw), 0
        while at < usize:
            if at + _HEAD.size > usize:
                raise Cut(f"chunk at byte {offset}: a record is cut")
            op, n = _HEAD.unpack_from(buf, at)
            at += _HEAD.size
            if n > usize - at:
                raise Cut(f"chunk at byte {offset}: a record is cut")
            out = records.take(op, buf, at, at + n)
            if out is not None:
                yield out
            at += n
