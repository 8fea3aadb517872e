"""Issue 32: files handed by a stranger are read strictly and in bounded memory and time.  Every bad CSV/NPZ cell,
encoding, size or dtype is a one-line DataError naming the file and where (line and column, or the array entry);
a decompression bomb in a run.mcap is refused before it is expanded (kexp/data/parse.py, recording/mcap_read.py)."""
import json
import os
import struct
import subprocess
import sys
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
import zstandard

from kexp.data import read_runs
from kexp.errors import ConfigError, DataError
from kexp.recording import read_log
from kexp.recording.mcap_file import MAGIC, McapFile
from kexp.recording.mcap_read import CHUNK_LIMIT, RATIO_LIMIT, budget
from kexp.recording.reader import LogError
from cli import console_script

ROOT = Path(__file__).resolve().parents[1]
HEADER = "t,x1,x2,u1"


def _rows(L=30, dt=0.01):
    """L samples of a 2-state, 1-input run as CSV lines (the last row's u empty)."""
    return [f"{k * dt!r},{0.5 + 0.01 * k!r},-0.5," + ("0.1" if k < L - 1 else "") for k in range(L)]


def _write(path: Path, lines, *, ending="\n", bom=False) -> Path:
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + ending.join([HEADER, *lines]).encode() + ending.encode())
    return path


def _read(path):
    return read_runs(path, n=2, m=1, dt=0.01)


def _refused(path, *pieces):
    with pytest.raises(DataError) as e:
        _read(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    for p in pieces:
        assert p in msg, (p, msg)
    return msg


# ---- CSV cells ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("cell, fragment", [
    ("1.31o", "'1.31o' is not a number"),
    ("0x1p-1", "'0x1p-1' is a hex float"),
    ("inf", "'inf': a run is measured or missing, never infinite"),
    ("-Infinity", "'-Infinity': a run is measured or missing, never infinite"),
    ("1e300", "1e300 is beyond ±1e+30"),
    ("1e400", "1e400 is beyond ±1e+30"),     # float() gives inf
    ("1_000", "'1_000' is not a number"),    # float() takes underscores
    ("٣", "'٣' is not a number"),             # float() takes Arabic-Indic digits
    ('"0.5"', "'\"0.5\"' is not a number"),
])
def test_a_bad_cell_names_file_line_and_column(tmp_path, cell, fragment):
    lines = _rows()
    lines[4] = lines[4].replace("-0.5", cell)      # data row 5 = line 6, column x2
    _refused(_write(tmp_path / "a.csv", lines), "line 6, column x2: ", fragment)


def test_the_range_limit_is_1e30_inclusive(tmp_path):
    lines = _rows()
    lines[3] = lines[3].replace("-0.5", "-1e30")
    ds = _read(_write(tmp_path / "a.csv", lines))
    assert ds.x[0, 3, 1] == -1e30
    lines[3] = lines[3].replace("-1e30", "-1.0000001e30")
    _refused(_write(tmp_path / "a.csv", lines), "line 5, column x2: -1.0000001e30 is beyond ±1e+30")


def test_empty_cells_and_nan_are_missing_samples(tmp_path):
    lines = _rows()
    lines[3] = lines[3].replace("-0.5", "")        # empty x2
    lines[7] = lines[7].replace("-0.5", " NaN ")   # any case, spaces around
    lines[9] = lines[9].replace(",0.1", ",nan")    # a missing input masks its sample
    ds = _read(_write(tmp_path / "a.csv", lines))
    assert np.flatnonzero(~ds.valid[0]).tolist() == [3, 7, 9]
    assert "3 NaN row(s) masked" in ds.report.lines()[0]


def test_a_missing_time_is_an_error(tmp_path):
    lines = _rows()
    lines[2] = "," + lines[2].split(",", 1)[1]
    _refused(_write(tmp_path / "a.csv", lines), "line 4, column t: no time")


def test_bom_and_crlf_are_read_like_plain_text(tmp_path):
    plain = _read(_write(tmp_path / "a.csv", _rows()))
    (tmp_path / "a.csv").unlink()
    other = _read(_write(tmp_path / "b.csv", _rows(), ending="\r\n", bom=True))
    assert np.array_equal(plain.x, other.x) and np.array_equal(plain.u, other.u)
    assert plain.x.shape == (1, 30, 2)


def test_quoted_header_names_spaces_and_blank_lines_are_accepted(tmp_path):
    p = tmp_path / "a.csv"
    lines = [", ".join(r.split(",")) for r in _rows()]
    lines.insert(5, "")
    p.write_text('"t","x1","x2","u1"\n' + "\n".join(lines) + "\n")
    ds = _read(p)
    assert ds.valid.all() and ds.x[0, 29, 0] == 0.5 + 0.01 * 29


@pytest.mark.parametrize("content, pieces", [
    ("t,x1,x1,u1\n" + "\n".join(_rows()) + "\n", ["duplicate column name(s) ['x1']"]),
    (HEADER + "\n", ["0 data row(s); a run needs at least 2 samples"]),
    ("", ["empty CSV file"]),
    (HEADER + "\n" + "\n".join(_rows()[:-1]) + "\n0.29,0.79", ["line 31: data row 30 has 2 cells, the header 4"]),
    (HEADER + "\r" + "\r".join(_rows()) + "\r", ["line 1 holds a carriage return inside it"]),
])
def test_layout_errors(tmp_path, content, pieces):
    p = tmp_path / "a.csv"
    p.write_text(content, newline="")
    _refused(p, *pieces)


def test_a_latin1_byte_is_named_by_line_and_byte_offset(tmp_path):
    p = tmp_path / "a.csv"
    lines = _rows()
    p.write_bytes(("\n".join([HEADER, *lines[:2]]) + "\n").encode() + b"0.02,0.52,-0.5,0.1 \xb0C\n")
    offset = len(("\n".join([HEADER, *lines[:2]]) + "\n0.02,0.52,-0.5,0.1 ").encode())
    _refused(p, f"line 4, byte offset {offset}: byte 0xb0 is not UTF-8; save the file as UTF-8")


def test_binary_files_named_csv(tmp_path):
    p = tmp_path / "a.csv"
    p.write_bytes(_npy(np.zeros((30, 4))))                               # an .npy renamed: NUL at byte 7
    _refused(p, "line 1 holds a NUL byte (byte offset 7): a binary file, not CSV text")
    p.write_bytes(zlib.compress(("\n".join([HEADER, *_rows()])).encode()))  # compressed: not UTF-8 first
    _refused(p, "line 1, byte offset 1: byte 0x9c is not UTF-8")
    p.write_bytes(HEADER.encode() + b"\n" + b"1" * 200_000 + b"\n")   # one 200 kB line
    _refused(p, "line 2 is longer than 65536 bytes")


def _peak_rss_growth_mb(code: str, env=None) -> tuple[float, str]:
    """Run ``code`` (which defines ``run()``) in a fresh interpreter: (peak RSS growth in MB over the state after
    imports, what run() printed or raised as one line)."""
    prog = ("import resource, sys\n" + code + "\nbase = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
            "try:\n    out = run()\nexcept Exception as exc:\n    out = f'{type(exc).__name__}: {exc}'\n"
            "peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\nprint((peak - base) / 1024)\nprint(out)\n")
    proc = subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True, timeout=120,
                          env={**os.environ, **(env or {})})
    assert proc.returncode == 0, proc.stderr[-2000:]
    growth, out = proc.stdout.splitlines()[-2:]
    return float(growth), out


def test_a_2_gib_file_of_nuls_is_refused_in_bounded_memory(tmp_path):
    p = tmp_path / "a.csv"
    with open(p, "wb") as fh:
        fh.truncate(2 << 30)                 # a sparse file: 2 GiB of NULs, nothing written to disk
    _refused(p, "2147483648 bytes, past the limit of 1024 MiB for one data file", "KEXP_DATA_FILE_LIMIT_MB")
    # with the limit raised past it, the first 64 KiB show a binary file; the line is never read whole
    code = f"from kexp.data import read_runs\ndef run():\n    read_runs({str(p)!r}, n=2, m=1, dt=0.01)"
    growth, out = _peak_rss_growth_mb(code, {"KEXP_DATA_FILE_LIMIT_MB": "4096"})
    assert out.startswith("DataError: ") and "line 1 holds a NUL byte (byte offset 0)" in out, out
    assert growth < 50, growth         # before: 4.4 GB RSS and a traceback


def test_the_file_limit_is_configurable(tmp_path, monkeypatch):
    p = _write(tmp_path / "a.csv", _rows(L=20_000))   # 0.5 MB
    assert _read(p).x.shape == (1, 20_000, 2)
    monkeypatch.setenv("KEXP_DATA_FILE_LIMIT_MB", "0")
    with pytest.raises(ConfigError, match="KEXP_DATA_FILE_LIMIT_MB='0': give a whole number of MiB >= 1"):
        _read(p)
    monkeypatch.setenv("KEXP_DATA_FILE_LIMIT_MB", "1")
    assert _read(p).x.shape == (1, 20_000, 2)
    p2 = _write(tmp_path / "b.csv", _rows(L=50_000))
    assert p2.stat().st_size > 1 << 20
    with pytest.raises(DataError, match=r"b.csv: \d+ bytes, past the limit of 1 MiB for one data file"):
        _read(p2)


# ---- NPZ ---------------------------------------------------------------------------------------------------

def _npz(path, **arrays):
    t = np.arange(30) * 0.01
    x = np.c_[np.linspace(0, 1, 30), np.zeros(30)]
    np.savez(path, **{"t": t, "x": x, **arrays})
    return path


@pytest.mark.parametrize("arrays, pieces", [
    ({"x": np.zeros((30, 2)) + 1j}, ["x holds complex numbers (complex128)", "save x.real"]),
    ({"x": np.zeros((30, 2), complex)}, ["x holds complex numbers"]),         # even a zero imaginary part
    ({"x": np.array([[None, 1.0]] * 30, dtype=object)}, ["x is an object array (a pickle); kexp never loads"]),
    ({"x": np.zeros((30, 2), bool)}, ["x has dtype bool"]),
    ({"x": np.array([["a", "b"]] * 30)}, ["x has dtype <U1"]),
    ({"x": np.r_[np.zeros((3, 2)), [[0.0, np.inf]], np.zeros((26, 2))]}, ["x[3, 1] = inf: a run is measured or "
                                                                          "missing, never infinite"]),
    ({"u": np.r_[np.zeros((2, 1)), [[-1e31]], np.zeros((26, 1))]}, ["u[2, 0] = -1e+31 is beyond ±1e+30"]),
])
def test_npz_values_and_dtypes(tmp_path, arrays, pieces):
    _refused(_npz(tmp_path / "a.npz", **arrays), *pieces)


def test_an_npz_declaring_a_huge_shape_is_refused_before_loading(tmp_path):
    header = {"descr": "<f8", "fortran_order": False, "shape": (10 ** 12, 2)}
    buf = __import__("io").BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    p = tmp_path / "a.npz"
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("t.npy", _npy(np.arange(30) * 0.01))
        z.writestr("x.npy", buf.getvalue() + bytes(480))
    _refused(p, "x declares shape (1000000000000, 2) (16000000000000 bytes) but its member holds 480 bytes")


def _npy(a) -> bytes:
    buf = __import__("io").BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def test_an_npz_zip_bomb_is_refused_from_its_declared_size(tmp_path, monkeypatch):
    """x of 2 MiB of zeros compresses to ~2 kB (t to ~0.3 MB); with the file limit at 1 MiB the members' declared
    size is refused before any is decompressed."""
    p = tmp_path / "a.npz"
    np.savez_compressed(p, t=np.arange(131072) * 0.01, x=np.zeros((131072, 2)))
    assert p.stat().st_size < 400_000
    monkeypatch.setenv("KEXP_DATA_FILE_LIMIT_MB", "1")
    _refused(p, "its arrays declare 3145984 bytes uncompressed, past the limit of 1 MiB", "(a zip bomb?)")


# ---- MCAP bombs --------------------------------------------------------------------------------------------

def _zeros_frame(size: int) -> bytes:
    """A zstd frame of ``size`` zero bytes, compressed in 1 MiB pieces (2 GiB -> 65 kB in ~0.5 s)."""
    obj = zstandard.ZstdCompressor(level=1).compressobj(size=size)
    block, parts = bytes(1 << 20), []
    for k in range(0, size, 1 << 20):
        parts.append(obj.compress(block[:min(1 << 20, size - k)]))
    return b"".join(parts) + obj.flush()


def _mcap(path: Path, declared: int, data: bytes, compression: bytes = b"zstd") -> Path:
    """magic, an empty Header (the chunk starts at byte 25), one Chunk declaring ``declared`` bytes."""
    header = struct.pack("<BQII", 1, 8, 0, 0)
    body = (struct.pack("<QQQII", 0, 0, declared, 0, len(compression)) + compression + struct.pack("<Q", len(data))
            + data)
    path.write_bytes(MAGIC + header + struct.pack("<BQ", 6, len(body)) + body)
    return path


@pytest.fixture(scope="module")
def bombs(tmp_path_factory):
    d = tmp_path_factory.mktemp("bombs")
    frame = _zeros_frame(2 << 30)
    return {
        "declared": _mcap(d / "declared.mcap", 2 << 30, frame),          # declares 2 GiB: the 65 kB file
        "lying": _mcap(d / "lying.mcap", 1000, frame),                   # declares 1000 bytes, makes 2 GiB
        "small": _mcap(d / "small.mcap", 48 << 20, _zeros_frame(48 << 20)),   # the 1.6 kB file: 48 MiB
    }


def test_mcap_bombs_are_refused_with_the_file_and_chunk_offset(bombs):
    assert 60_000 < bombs["declared"].stat().st_size < 70_000 and bombs["small"].stat().st_size < 2_000
    cases = {"declared": "the chunk at byte 25 declares 2048 MiB uncompressed, past the limit of 64 MiB per chunk",
             "lying": "the chunk at byte 25 decompresses past the 1000 bytes it declares",
             "small": "the chunk at byte 25 brings the declared uncompressed size to 48 MiB, past this file's "
                      f"budget of {budget(bombs['small'].stat().st_size) / (1 << 20):.4g} MiB"}
    for name, fragment in cases.items():
        with pytest.raises(LogError) as e:
            read_log(bombs[name])
        assert str(e.value).startswith(f"{bombs[name]}: {fragment}"), str(e.value)
        with pytest.raises(DataError, match="decompress"):   # as data, the same refusal
            _read(bombs[name])
    # the budget: a 1.6 kB file may make ~1.1 MiB, kexp's own logs (2.4-5.6x) are far inside it
    assert budget(1600) == RATIO_LIMIT * 1600 + (1 << 20) < 1.2 * (1 << 20) and CHUNK_LIMIT == 64 << 20


def test_mcap_bombs_cost_bounded_memory(bombs):
    for name in ("declared", "lying"):
        code = f"from kexp.recording import read_log\ndef run():\n    read_log({str(bombs[name])!r})"
        growth, out = _peak_rss_growth_mb(code)
        assert out.startswith("LogError: ") and "chunk at byte 25" in out, out
        assert growth < 50, (name, growth)      # before: 2 GiB allocated (declared), a hang past 120 s


def test_a_chunk_within_the_budget_is_read_and_a_cut_stays_a_warning(tmp_path):
    """1 MiB of zero records (116 508 empty records of unknown opcode 0) fits a 1.6 kB file's budget: they parse as
    skipped records, the file has no footer, so the log is read as cut short (a warning), not refused."""
    p = _mcap(tmp_path / "run.mcap", 9 * 116_508, _zeros_frame(9 * 116_508))
    log = read_log(p)
    assert log.truncated and log.channels == {} and "run.mcap is truncated (the file ends before its footer)" \
        in log.warning


def test_lz4_and_unknown_compressions(tmp_path):
    import lz4.frame
    p = _mcap(tmp_path / "run.mcap", 1000, lz4.frame.compress(bytes(16 << 20)), b"lz4")   # 16 MiB in ~64 kB
    with pytest.raises(LogError, match="run.mcap: the chunk at byte 25 decompresses past the 1000 bytes it declares"):
        read_log(p)
    log = read_log(_mcap(tmp_path / "b.mcap", 1000, bytes(10), b"brotli"))
    assert log.truncated and "b.mcap is truncated (unknown compression 'brotli')" in log.warning


def _step_log(path: Path, steps) -> Path:
    """A finished MCAP log whose /step channel holds ``steps`` (JSON text each), written by kexp's framing."""
    with open(path, "wb") as fh:
        w = McapFile(fh)
        w.start()
        cid = w.register_channel("/step", "json", w.register_schema("step", "jsonschema", b"{}"))
        w.add_messages((cid, k, k, k, s.encode()) for k, s in enumerate(steps))
        w.finish()
    return path


@pytest.mark.parametrize("second, fragment", [
    ('{"t": 0.01, "x": [0.1, "a"], "u": [0.0]}', "/step message 2: x holds 'a', not a number"),
    ('{"t": 0.01, "x": [0.1, Infinity], "u": [0.0]}', "/step.x[1, 1] = inf: a run is measured or missing"),
    ('{"t": 0.01, "x": [0.1, 0.2], "u": [1e31]}', "/step.u[1, 0] = 1e+31 is beyond ±1e+30"),
    ('[1, 2]', "a /step message is not a JSON object"),
])
def test_mcap_step_values_are_read_strictly(tmp_path, second, fragment):
    first = '{"t": 0.0, "x": [0.1, 0.2], "u": [0.0]}'
    p = _step_log(tmp_path / "run.mcap", [first, second, first.replace("0.0,", "0.02,", 1)])
    _refused(p, fragment)


def test_a_corrupt_chunk_past_its_crc_is_a_cut_not_a_refusal(tmp_path):
    """A kexp log whose second chunk has one flipped byte in its compressed data: what precedes it is read."""
    p = tmp_path / "run.mcap"
    with open(p, "wb") as fh:
        w = McapFile(fh, chunk_size=200)
        w.start()
        sid = w.register_schema("s", "jsonschema", b"{}")
        cid = w.register_channel("/step", "json", sid)
        w.add_messages((cid, k, k, k, json.dumps({"k": k, "pad": "x" * 150}).encode()) for k in range(6))
        w.finish()
    data = bytearray(p.read_bytes())
    second = data.find(b"zstd", data.find(b"zstd") + 4) + 4 + 8 + 5   # inside the second chunk's zstd data
    data[second] ^= 0xFF
    p.write_bytes(bytes(data))
    log = read_log(p)
    assert log.truncated and [m["k"] for m in log.messages("/step")] == [0]   # the first chunk: one message
    assert "run.mcap is truncated (chunk at byte" in log.warning


# ---- through the commands: one line, exit code 2 -----------------------------------------------------------

def test_kexp_diff_on_a_bomb_exits_2_with_one_line(bombs):
    proc = subprocess.run([console_script("kexp-diff"), str(bombs["declared"]), str(ROOT / "recordings" / "paper_vanderpol.mcap")],
                          capture_output=True, text=True, timeout=60)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert lines[0].startswith(f"kexp-diff: error: {bombs['declared']}: the chunk at byte 25 declares 2048 MiB")


def test_kexp_refuses_handed_files_with_one_line_and_exit_code_2(tmp_path, bombs):
    lines = _rows(L=300)
    lines[41] = lines[41].replace("-0.5", "1.31o")
    (tmp_path / "typo").mkdir()
    _write(tmp_path / "typo" / "run.csv", lines)
    (tmp_path / "latin1").mkdir()
    (tmp_path / "latin1" / "run.csv").write_bytes(b"t,x1,x2 \xb0C\n0.0,1.0,2.0\n")
    cases = [(tmp_path / "typo", "typo/run.csv: line 43, column x2: '1.31o' is not a number"),
             (tmp_path / "latin1", "latin1/run.csv: line 1, byte offset 8: byte 0xb0 is not UTF-8"),
             (bombs["declared"], "declared.mcap: the chunk at byte 25 declares 2048 MiB uncompressed")]
    for i, (path, fragment) in enumerate(cases):   # each case its own run folder
        proc = subprocess.run(
            [console_script("kexp"), "data.source.kind=files", f"data.source.path={path}", "dictionary.degree=3",
             "identification.holdout=0", "logging.rrd=false", "logging.progress=false", "cache.enabled=false",
             f"hydra.run.dir={tmp_path / f'out{i}'}"], capture_output=True, text=True, timeout=120)
        err = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(err) == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
        assert err[0].startswith("kexp: error: ") and fragment in err[0], err[0]


def test_the_dictionary_range_check_follows_degree_scale_and_count():
    """count·max(1, |ξ|)^(2·degree) must stay below 1e308: 1e30 (the files' limit) passes degree 5 over up to 1e8
    samples and fails degree 8 (measured: a traceback with method=gram), unless the dictionary scales it."""
    from kexp.data.runs import SampleStats, check_dictionary_range

    def stats(count, top):
        return SampleStats(count=count, low=np.array([-0.5, -top]), high=np.array([0.5, top]),
                           absmax=np.array([0.5, top]), sumsq=np.zeros(2), center=np.zeros(2))
    check_dictionary_range(stats(10 ** 8, 1e30), 5)
    with pytest.raises(DataError, match=r"the data reach \|x2\| = 1e\+30: monomials up to dictionary.degree=5 reach "
                                        r"1e150 and their sums of squares over 1000000000 samples 1e309"):
        check_dictionary_range(stats(10 ** 9, 1e30), 5)
    with pytest.raises(DataError, match=r"degree=8 reach 1e240 .* over 300 samples 1e482, past the float range"):
        check_dictionary_range(stats(300, 1e30), 8)
    check_dictionary_range(stats(300, 1e30), 8, scale=[1.0, 1e30])              # dictionary.scale=auto
    check_dictionary_range(stats(300, 1e30), 8, scale=[1.0, 1e30], center=[0.0, 0.0])
    with pytest.raises(DataError, match=r"\|x2\| = 1e\+30 \(scaled: 1e\+20\)"):
        check_dictionary_range(stats(300, 1e30), 8, scale=[1.0, 1e10])
    check_dictionary_range(stats(10 ** 12, 0.9), 50)                              # |ξ| < 1 never grows
