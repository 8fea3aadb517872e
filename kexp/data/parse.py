"""Strict reading of recorded CSV and NPZ files: every cell a decimal number or a marked missing sample, in bounded
memory; anything else is a one-line :class:`~kexp.errors.DataError` naming the file and where in it.

Rules (README, "Data from files"):

- **Missing vs wrong.**  An empty cell or ``nan`` (any case, NaN in an NPZ) marks a missing sample: its row is
  masked and counted in the report.  Text where a number belongs (``1.31o``), a hex float (``0x1p-1``: Python's
  float() takes it, CSV data does not hold it), ``inf``/``-inf`` (a run is measured or missing, never infinite)
  and values beyond ±:data:`VALUE_LIMIT` are errors.
- **Range.**  |value| ≤ 1e30: the default dictionary (monomials up to degree 5 of the raw state) then stays
  below 1e150 and its squares (Gram sums, sums of squares over up to 1e8 samples) below 1e308; 1e300 in one cell
  overflowed and ended in a LinAlgError traceback.  Larger numbers mean other units: rescale the column.
- **Text.**  UTF-8 (a byte-order mark is skipped), ``\\n`` or ``\\r\\n`` line endings; a byte that is not UTF-8
  is named by line and byte offset; a NUL byte means a binary file.  Blank lines are skipped; line numbers are
  1-based as an editor shows them.  Cells are separated by commas and may carry spaces around them; header names
  may be quoted with double quotes.
- **Size.**  A line may hold at most :data:`LINE_LIMIT` bytes (64 KiB, some 2 600 numbers) and a file at most
  :func:`file_limit` bytes (default 1 GiB, ``KEXP_DATA_FILE_LIMIT_MB`` to change it); both are checked before
  the line or file is read, so memory stays bounded (a 2 GiB file without a newline is refused at its size, a
  200 kB line after 64 KiB).
- **NPZ.**  Each member's header is read first (nothing else is): only real numbers (integer or float dtypes;
  complex arrays are refused, even with a zero imaginary part: save ``x.real``), never objects (kexp loads no
  pickle: ``allow_pickle=False``); a member's declared uncompressed size (the zip's) must hold its declared shape
  and, over all members, stay within the file limit, so a zip bomb or a lying shape is refused before anything is
  allocated.
"""
from __future__ import annotations

import os
import re
import zipfile
from array import array
from pathlib import Path

import numpy as np

from ..errors import ConfigError, DataError

VALUE_LIMIT = 1e30          # largest |value| of a recorded sample (see the module docstring)
LINE_LIMIT = 64 << 10       # bytes of one CSV line, its line ending included
FILE_LIMIT_MB = 1024        # default file limit in MiB; the environment variable below overrides it
FILE_LIMIT_ENV = "KEXP_DATA_FILE_LIMIT_MB"

_NUM = r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
_NUMBER = re.compile(_NUM)
_ROW = re.compile(rf"[ \t]*{_NUM}[ \t]*(?:,[ \t]*{_NUM}[ \t]*)*")   # a row of numbers only: the fast path
_MISSING = ("", "nan", "+nan", "-nan")
_INF = ("inf", "+inf", "-inf", "infinity", "+infinity", "-infinity")
_HEX = re.compile(r"[+-]?0[xX]")
_MISSING_HINT = "leave the cell empty or write nan for a missing sample"


def file_limit() -> int:
    """Bytes a data file (and an NPZ's members together, uncompressed) may hold: ``KEXP_DATA_FILE_LIMIT_MB`` MiB
    if set (a positive integer), else 1 GiB."""
    raw = os.environ.get(FILE_LIMIT_ENV)
    if raw is None:
        return FILE_LIMIT_MB << 20
    if not raw.strip().isdigit() or int(raw) < 1:
        raise ConfigError(f"{FILE_LIMIT_ENV}={raw!r}: give a whole number of MiB >= 1 (default {FILE_LIMIT_MB})")
    return int(raw) << 20


def check_file_size(f: Path) -> None:
    size, limit = f.stat().st_size, file_limit()
    if size > limit:
        raise DataError(f"{f}: {size} bytes, past the limit of {limit >> 20} MiB for one data file; split the run "
                        f"or raise {FILE_LIMIT_ENV}")


def _cell(f: Path, text: str, line: int, column: str) -> float:
    """The number in one CSV cell (NaN for a missing sample), or a DataError naming line and column."""
    s = text.strip(" \t")
    low = s.lower()
    where = f"{f}: line {line}, column {column}"
    if low in _MISSING:
        return np.nan
    if _NUMBER.fullmatch(s) is None:
        shown = s if len(s) <= 40 else s[:37] + "..."
        if low in _INF:
            raise DataError(f"{where}: {shown!r}: a run is measured or missing, never infinite; {_MISSING_HINT}")
        if _HEX.match(s):
            raise DataError(f"{where}: {shown!r} is a hex float; write decimal numbers (e.g. 0.5)")
        raise DataError(f"{where}: {shown!r} is not a number; write a decimal number (e.g. 1.31 or -2.5e-3), "
                        f"or {_MISSING_HINT}")
    v = float(s)
    if not abs(v) <= VALUE_LIMIT:
        raise DataError(f"{where}: {s} is beyond ±{VALUE_LIMIT:g}, kexp's range for recorded values (its "
                        "monomials and their squares must stay finite); rescale the column (other units)")
    return v


def check_line(f: Path, number: int, offset: int, raw: bytes) -> str:
    """The text of one raw CSV line (line ``number``, 1-based, at byte ``offset``), its line ending removed, after
    the checks of the module docstring (NUL byte, length, UTF-8, stray carriage return)."""
    nul = raw.find(b"\0")
    if nul >= 0:
        raise DataError(f"{f}: line {number} holds a NUL byte (byte offset {offset + nul}): a binary file, "
                        "not CSV text")
    if len(raw) > LINE_LIMIT:
        raise DataError(f"{f}: line {number} is longer than {LINE_LIMIT} bytes (64 KiB), the limit for one "
                        "line; is it a CSV file of recorded runs?")
    skip = 3 if number == 1 and raw.startswith(b"\xef\xbb\xbf") else 0
    try:
        text = raw[skip:].decode("utf-8")
    except UnicodeDecodeError as exc:
        bad = raw[skip + exc.start]
        raise DataError(f"{f}: line {number}, byte offset {offset + skip + exc.start}: byte 0x{bad:02x} is "
                        "not UTF-8; save the file as UTF-8") from None
    text = text[:-2] if text.endswith("\r\n") else text[:-1] if text.endswith("\n") else text
    if "\r" in text:
        raise DataError(f"{f}: line {number} holds a carriage return inside it (old Mac line endings?); "
                        "use \\n or \\r\\n line endings")
    return text


def _lines(f: Path):
    """(1-based line number, text without its line ending) of each line of a UTF-8 text file, read one line at a
    time with at most LINE_LIMIT bytes each."""
    with open(f, "rb") as fh:
        number, offset = 0, 0
        while True:
            raw = fh.readline(LINE_LIMIT + 1)
            if not raw:
                return
            number += 1
            text = check_line(f, number, offset, raw)
            offset += len(raw)
            yield number, text


def _header_name(cell: str) -> str:
    s = cell.strip(" \t")
    return s[1:-1] if len(s) >= 2 and s[0] == s[-1] == '"' else s


def parse_header(f: Path, text: str) -> list[str]:
    """The column names of the header line ``text`` (quotes removed); a DataError for duplicate names."""
    header = [_header_name(c) for c in text.split(",")]
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise DataError(f"{f}: duplicate column name(s) {dup} in the header; name each column once")
    return header


def read_csv(f: Path) -> tuple[list[str], np.ndarray, list[int]]:
    """(header names, values (rows, columns) with NaN for missing cells, 1-based line of each row) of a CSV file,
    read strictly (module docstring).  A row must have one cell per header column; a missing time (t) is an
    error."""
    check_file_size(f)
    lines = _lines(f)
    header = None
    for _number, text in lines:
        if text.strip(" \t"):
            header = parse_header(f, text)
            break
    if header is None:
        raise DataError(f"{f}: empty CSV file; expected a header row t,x1,…,xn[,u1,…,um]")
    width = len(header)
    values, rows = array("d"), []
    for number, text in lines:
        if not text.strip(" \t"):
            continue
        values.extend(parse_row(f, text, number, header, len(rows) + 1))
        rows.append(number)
    return header, np.frombuffer(values, dtype=float).reshape(len(rows), width), rows


def parse_row(f: Path, text: str, number: int, header: list[str], row_index: int) -> list[float]:
    """The values of the non-blank data row ``text`` (line ``number``, data row ``row_index``, 1-based) with NaN
    for missing cells; a one-line DataError naming line and column for a wrong cell count or a bad cell."""
    cells = text.split(",")
    if len(cells) != len(header):
        raise DataError(f"{f}: line {number}: data row {row_index} has {len(cells)} cells, the header "
                        f"{len(header)}; give one cell per column (empty for the last row's u)")
    row = list(map(float, cells)) if _ROW.fullmatch(text) else None
    if row is None or max(map(abs, row)) > VALUE_LIMIT:   # a missing or a bad cell: cell by cell
        row = [_cell(f, c, number, h) for c, h in zip(cells, header)]
        if "t" in header and np.isnan(row[header.index("t")]):
            raise DataError(f"{f}: line {number}, column t: no time; every sample needs its time")
    return row


def check_values(f: Path, name: str, a: np.ndarray) -> None:
    """A DataError naming the first entry of the array ``name`` of an NPZ that is infinite or beyond ±VALUE_LIMIT
    (NaN is a missing sample and passes)."""
    bad = np.abs(a) > VALUE_LIMIT          # False for NaN
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        v = a[idx]
        where = f"{f}: {name}[{', '.join(map(str, idx))}] = {v:g}"
        if np.isinf(v):
            raise DataError(f"{where}: a run is measured or missing, never infinite; write NaN for a missing sample")
        raise DataError(f"{where} is beyond ±{VALUE_LIMIT:g}, kexp's range for recorded values (its monomials and "
                        "their squares must stay finite); rescale it (other units)")


def npz_headers(f: Path) -> dict[str, tuple]:
    """{array name: shape} of an .npz, from the members' headers alone, after the checks of the module docstring
    (real dtypes, declared sizes within the file limit, shapes that fit their members, no duplicates)."""
    check_file_size(f)
    limit = file_limit()
    try:
        with zipfile.ZipFile(f) as z:
            infos = z.infolist()
            names = [i.filename for i in infos]
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise DataError(f"{f}: member(s) {dup} appear twice in the archive; save each array once")
            total = sum(i.file_size for i in infos)
            if total > limit:
                raise DataError(f"{f}: its arrays declare {total} bytes uncompressed, past the limit of "
                                f"{limit >> 20} MiB for one data file (a zip bomb?); split the run or raise "
                                f"{FILE_LIMIT_ENV}")
            out = {}
            for info in infos:
                name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                with z.open(info) as fh:
                    major, _minor = np.lib.format.read_magic(fh)
                    read = np.lib.format.read_array_header_1_0 if major == 1 else \
                        np.lib.format.read_array_header_2_0
                    shape, _fortran, dtype = read(fh)
                    head = fh.tell()
                if dtype.hasobject:
                    raise DataError(f"{f}: {name} is an object array (a pickle); kexp never loads pickles: save "
                                    "arrays of numbers")
                if dtype.kind == "c":
                    raise DataError(f"{f}: {name} holds complex numbers ({dtype}); recorded runs are real: save "
                                    f"{name}.real if its imaginary part is zero")
                if dtype.kind not in "iuf" or dtype.fields is not None:
                    raise DataError(f"{f}: {name} has dtype {dtype}; save an array of numbers (float or int)")
                nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if nbytes > info.file_size - head:
                    raise DataError(f"{f}: {name} declares shape {shape} ({nbytes} bytes) but its member holds "
                                    f"{info.file_size - head} bytes; a corrupt or forged .npz")
                out[name] = shape
            return out
    except DataError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        msg = (str(exc).splitlines() or [""])[0]
        raise DataError(f"{f}: not a readable .npz file ({type(exc).__name__}: {msg})") from None
