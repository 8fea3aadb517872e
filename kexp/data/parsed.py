"""Recorded CSV files parsed once: each file is parsed (strictly, :mod:`kexp.data.parse`) into a float64 ``.npy``
entry named by the SHA-256 of the file's bytes, and every later pass over the runs (statistics, split, the fit,
the noise diagnostic, the quality windows, ...) reads that entry memory-mapped instead of the text.

Why a binary cache on disk rather than the parsed runs kept in memory: a pass holds one run at a time
(kexp.data.streaming), so keeping every run in memory would undo the bounded memory of streaming; a
memory-mapped entry costs no resident memory beyond the pages a pass touches (the OS drops them under pressure),
is 2-3× smaller than the text, and is shared by construction by every job of a sweep that uses the same cache
folder (``cache.dir``): a second job, or a second run, parses nothing.

- **Entry**: ``<dir>/csv-<sha256 of the bytes, 40 hex>-v<PARSE_VERSION>.npy`` (values, NaN for missing cells) and
  ``.json`` beside it (the header).  Named by content, so a changed file (same name, new content) is parsed
  again, and identical files share one entry.  Bump :data:`PARSE_VERSION` when parsing changes.
- **Concurrency**: the header and then the values are written to temporary files (pid and a random suffix)
  and renamed into place (``os.replace``, atomic on one file system), the values last: a reader that sees the
  ``.npy`` sees a complete entry; two jobs parsing the same file at once both write a whole entry, the last
  rename wins, both are equal.  An unreadable entry (truncated, foreign) is parsed again and replaced.
- **Parsing in bounded memory**: :func:`parse_csv_to_npy` reads blocks of :data:`BLOCK_BYTES`, checks a block's
  rows at once (a regular expression per line, numbers converted by ``float``, exact), appends them to
  the ``.npy`` file and forgets them; a block with anything else (a missing or bad cell, a blank line, a
  non-UTF-8 byte, ...) is read line by line by :mod:`kexp.data.parse`'s own functions, so errors are the same
  one-line messages naming the file, line and column.  Peak memory: ~14 blocks (some 4 MB: a block's lines,
  cells and floats), whatever the row count.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import secrets
import tempfile
import warnings
import weakref
from pathlib import Path

import numpy as np

from ..errors import DataError
from .parse import LINE_LIMIT, VALUE_LIMIT, _NUM, check_file_size, check_line, parse_header, parse_row

PARSE_VERSION = 1            # part of an entry's name: bump when parsing or the entry's layout changes
BLOCK_BYTES = 1 << 18        # text read and checked at once (peak memory ~14 times this: lines, cells, floats)
_HEADER_BYTES = 128          # the .npy header, written with a fixed length so the shape can be filled in at the end
_COUNTS = {"parsed": 0, "hits": 0}   # parses and cache hits in this process (tests, benchmarks/files.py)


def counts() -> dict:
    """{"parsed": CSV files parsed, "hits": entries read instead} in this process so far (a copy)."""
    return dict(_COUNTS)


def file_digest(f: Path) -> str:
    """SHA-256 (hex) of the file's bytes, read in 64 KiB blocks (after the file-size limit is checked)."""
    check_file_size(f)
    h = hashlib.sha256()
    with open(f, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 16), b""):
            h.update(block)
    return h.hexdigest()


def _npy_header(rows: int, width: int) -> bytes:
    text = repr({"descr": "<f8", "fortran_order": False, "shape": (rows, width)})
    head = b"\x93NUMPY\x01\x00"
    pad = _HEADER_BYTES - len(head) - 2 - len(text) - 1
    return head + (_HEADER_BYTES - len(head) - 2).to_bytes(2, "little") + text.encode() + b" " * pad + b"\n"


def _block_pattern(width: int) -> re.Pattern:
    """One clean row of ``width`` numbers (its \\r of a CRLF ending allowed), matched line by line: one
    expression over a whole block would make the regular-expression engine keep a backtracking record per line
    (some 90 MB for a 1 MiB block)."""
    row = rf"[ \t]*{_NUM}[ \t]*" + rf"(?:,[ \t]*{_NUM}[ \t]*){{{width - 1}}}"
    return re.compile(rf"{row}\r?")


def parse_csv_to_npy(f: Path, out: Path) -> list[str]:
    """Parse the CSV file ``f`` strictly (the rules and messages of :mod:`kexp.data.parse`) into the ``.npy``
    file ``out`` (float64, (rows, columns), NaN for missing cells), block by block in bounded memory; returns
    the header's column names."""
    check_file_size(f)
    with open(f, "rb") as fh, open(out, "wb") as dst:
        number, offset, header = 0, 0, None
        while header is None:   # the header: the first non-blank line
            raw = fh.readline(LINE_LIMIT + 1)
            if not raw:
                raise DataError(f"{f}: empty CSV file; expected a header row t,x1,…,xn[,u1,…,um]")
            number += 1
            text = check_line(f, number, offset, raw)
            offset += len(raw)
            if text.strip(" \t"):
                header = parse_header(f, text)
        width = len(header)
        pattern = _block_pattern(width)
        dst.write(_npy_header(0, width))
        rows, rest = 0, b""
        while True:
            block = fh.read(BLOCK_BYTES)
            data = rest + block
            if not data:
                break
            cut = data.rfind(b"\n") + 1 if block else len(data)
            if cut == 0:   # no line end in this block yet
                if len(data) > LINE_LIMIT:
                    check_line(f, number + 1, offset, data[:LINE_LIMIT + 1])   # raises: the line is too long
                rest = data
                continue
            chunk, rest = data[:cut], data[cut:]
            values, n_lines = _fast(chunk, pattern, width)
            if values is None:   # anything but clean rows: line by line, kexp.data.parse's checks and messages
                values, n_lines = _slow(f, chunk, number, offset, header, rows)
            dst.write(values.tobytes())
            rows += values.shape[0]
            number += n_lines
            offset += len(chunk)
        dst.seek(0)
        dst.write(_npy_header(rows, width))
    return header


def _fast(chunk: bytes, pattern: re.Pattern, width: int):
    """(values (rows, width), lines) of a block of complete lines that are all clean rows of numbers within
    ±VALUE_LIMIT, else (None, 0)."""
    if b"\0" in chunk or len(chunk) > BLOCK_BYTES + LINE_LIMIT:
        return None, 0
    try:
        text = chunk.decode("utf-8")
    except UnicodeDecodeError:
        return None, 0
    body = text[:-1] if text.endswith("\n") else text   # a block ends with its last line's "\n" (but at the end)
    lines = body.split("\n")
    if max(map(len, lines)) + 1 > LINE_LIMIT:   # first: a line over the limit (characters ≤ bytes), slow path
        return None, 0
    if not all(map(pattern.fullmatch, lines)):
        return None, 0
    cells = body.replace("\r", "").replace("\n", ",").split(",")
    values = np.fromiter(map(float, cells), dtype=float, count=len(cells)).reshape(len(lines), width)
    if not np.abs(values).max(initial=0.0) <= VALUE_LIMIT:
        return None, 0
    return values, len(lines)


def _slow(f: Path, chunk: bytes, number: int, offset: int, header: list[str], rows: int):
    out, n_lines = [], 0
    parts = chunk.split(b"\n")
    for raw in [p + b"\n" for p in parts[:-1]] + ([parts[-1]] if parts[-1] else []):
        n_lines += 1
        text = check_line(f, number + n_lines, offset, raw)
        offset += len(raw)
        if text.strip(" \t"):
            out.append(parse_row(f, text, number + n_lines, header, rows + len(out) + 1))
    return np.array(out, dtype=float).reshape(len(out), len(header)), n_lines


class ParsedStore:
    """Parsed CSV entries in ``directory`` (None: a private temporary folder removed when the store is
    garbage-collected or the process exits): :meth:`csv` gives a file's (header, values memory-mapped)."""

    def __init__(self, directory: str | Path | None = None):
        if directory is None:
            tmp = tempfile.TemporaryDirectory(prefix="kexp-parsed-")
            self._tmp = tmp
            directory = tmp.name
        self.dir = Path(directory)
        self._fallback: "ParsedStore | None" = None

    def paths(self, digest: str) -> tuple[Path, Path]:
        stem = f"csv-{digest[:40]}-v{PARSE_VERSION}"
        return self.dir / f"{stem}.npy", self.dir / f"{stem}.json"

    def _read(self, digest: str):
        npy, meta = self.paths(digest)
        try:
            header = json.loads(meta.read_text())
            values = np.load(npy, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError):
            return None
        if not (isinstance(header, list) and values.dtype == np.float64 and values.ndim == 2
                and values.shape[1] == len(header)):
            return None
        return header, values

    def csv(self, f: Path, digest: str | None = None) -> tuple[list[str], np.ndarray]:
        """(header, values (rows, columns) read-only, memory-mapped) of the CSV file ``f`` whose bytes have the
        SHA-256 ``digest`` (None: computed here): read from its entry, or parsed once into it.  A folder that
        cannot be created or written gives one warning, and this store then parses into the process's private
        temporary store (nothing is lost; only the sharing with other processes)."""
        digest = digest or file_digest(f)
        if self._fallback is not None:
            return self._fallback.csv(f, digest)
        found = self._read(digest) if self.paths(digest)[0].exists() else None
        if found is not None:
            _COUNTS["hits"] += 1
            return found
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            probe = self.dir / f".probe.{os.getpid()}.{secrets.token_hex(4)}"
            probe.touch()
            probe.unlink()
        except OSError as exc:
            warnings.warn(f"parsed-data cache {self.dir}: cannot write there ({type(exc).__name__}: "
                          f"{exc.strerror or exc}); CSV files are parsed into a temporary folder instead and not "
                          "shared with other runs (give a writable cache.dir)", RuntimeWarning, stacklevel=2)
            self._fallback = private_store()
            return self._fallback.csv(f, digest)
        npy, meta = self.paths(digest)
        tag = f".{os.getpid()}.{secrets.token_hex(4)}.tmp"
        tmp_npy, tmp_meta = npy.with_name(npy.name + tag), meta.with_name(meta.name + tag)
        try:
            header = parse_csv_to_npy(f, tmp_npy)
            _COUNTS["parsed"] += 1
            tmp_meta.write_text(json.dumps(header))
            os.replace(tmp_meta, meta)
            os.replace(tmp_npy, npy)   # last: a reader that sees the values sees the whole entry
        finally:
            for p in (tmp_npy, tmp_meta):
                p.unlink(missing_ok=True)
        found = self._read(digest)
        if found is None:   # pragma: no cover - only if another process broke the entry in between
            raise DataError(f"{f}: its parsed copy {npy} could not be read back; check the cache folder")
        return found


_DEFAULT: "weakref.ref | None" = None


def private_store() -> ParsedStore:
    """The process's temporary store (for open_runs without a cache folder): one per process, removed at exit."""
    global _DEFAULT
    store = _DEFAULT() if _DEFAULT is not None else None
    if store is None:
        store = ParsedStore(None)
        _DEFAULT = weakref.ref(store)
    return store
