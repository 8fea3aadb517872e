"""Recorded CSV files parsed once (issue 35 item 4, kexp.data.parsed): one parse per file per identification, none
with a warm cache, entries bit-identical to the strict line-by-line reader, a changed file parsed again, concurrent
writers that cannot corrupt an entry, the same one-line errors, and an unwritable folder that only costs sharing."""
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from kexp.app.build import parsed_dir, read_data_files
from kexp.data import Circle, DataConfig, collect, open_runs, write_runs
from kexp.data import parsed
from kexp.data.files import DataSource
from kexp.data.parse import read_csv
from kexp.data.parsed import ParsedStore, counts, file_digest, parse_csv_to_npy
from kexp.dictionary import Monomials
from kexp.errors import DataError
from kexp.identify import IdentifyConfig, identify
from kexp.systems import make_system

VDP = make_system("vanderpol", {})
KW = dict(n=2, m=1, dt=0.01, system_name="vanderpol", x_eq=VDP.equilibrium)

# a CSV with every accepted form: BOM, CRLF, spaces, quoted names, blank lines, empty cells and nan, 1. .5 1e5 -0
ODD = ('\ufeff"t", x1 ,x2,u1\r\n0,1.,.5,-0\r\n\r\n0.01, 1e-3 ,nan,2.5E+2\n0.02,,+3,\n'
       + "".join(f"{0.01 * k!r},{float(np.sin(k))!r},{float(-np.cos(k) / 7)!r},{k % 3 - 1}\n" for k in range(3, 400))
       + "4.0,1,2,\n")


def _delta(before: dict) -> dict:
    now = counts()
    return {k: now[k] - before[k] for k in now}


def _runs(folder: Path, n_runs: int = 4) -> Path:
    ds = collect(VDP, Circle(n_runs, 2.0), DataConfig(T=1.0))
    write_runs(ds, folder, "csv")
    return folder


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes()


def test_each_file_is_parsed_once_per_identification_and_never_with_a_warm_cache(tmp_path):
    folder, cache = _runs(tmp_path / "runs"), tmp_path / "parsed"
    before = counts()
    src = open_runs(folder, parsed_dir=cache, **KW)
    model = identify(VDP, src, Monomials(2, 3), IdentifyConfig())   # statistics, split, fit, validation: many passes
    assert _delta(before)["parsed"] == 4          # the 4 files, once each, whatever the number of passes
    assert _delta(before)["hits"] > 4             # the later passes read the entries
    assert len(list(cache.glob("csv-*.npy"))) == 4 and not list(cache.glob("*.tmp"))
    before = counts()
    again = identify(VDP, open_runs(folder, parsed_dir=cache, **KW), Monomials(2, 3), IdentifyConfig())
    assert _delta(before)["parsed"] == 0          # a second run (or another job of a sweep): nothing parsed
    assert np.array_equal(again.Lambda, model.Lambda) and np.array_equal(again.C, model.C)


def test_identify_gives_the_same_model_bit_for_bit_with_and_without_the_cache(tmp_path):
    """The CSV runs (written with repr, exact) through a cold and a warm cache, and the same runs as NPZ (no
    parsing at all): the same model, bit for bit."""
    ds = collect(VDP, Circle(5, 2.0), DataConfig(T=1.0))
    write_runs(ds, tmp_path / "csv", "csv")
    write_runs(ds, tmp_path / "npz", "npz")
    cfg = IdentifyConfig(holdout=0.2)
    models = [identify(VDP, open_runs(tmp_path / "csv", parsed_dir=tmp_path / "c", **KW), Monomials(2, 3), cfg)
              for _ in range(2)]
    models.append(identify(VDP, open_runs(tmp_path / "npz", **KW), Monomials(2, 3), cfg))
    for m in models[1:]:
        for name in ("Lambda", "B", "C", "T"):
            assert _same_bits(getattr(m, name), getattr(models[0], name)), name
        assert m.report["prediction_error"] == models[0].report["prediction_error"]


@pytest.mark.parametrize("block", [1 << 20, 97, 4096])
def test_the_entry_equals_the_strict_reader_bit_for_bit(tmp_path, monkeypatch, block):
    """Blocks of 97 bytes cut lines (and the CRLF pairs) anywhere: the entry still holds the line-by-line reader's
    values, NaN included, bit for bit."""
    monkeypatch.setattr(parsed, "BLOCK_BYTES", block)
    f = tmp_path / "odd.csv"
    f.write_bytes(ODD.encode())
    header, values, _lines = read_csv(f)
    got_header, got = ParsedStore(tmp_path / "c").csv(f)
    assert got_header == header == ["t", "x1", "x2", "u1"]
    assert values.shape == (401, 4) and np.isnan(values).sum() == 4 and _same_bits(got, values)
    assert not got.flags.writeable   # memory-mapped read-only: a pass cannot change the entry


def test_a_changed_file_is_parsed_again_and_a_broken_entry_replaced(tmp_path):
    f, store = tmp_path / "run.csv", ParsedStore(tmp_path / "c")
    f.write_text("t,x1\n0,1\n0.1,2\n")
    assert store.csv(f)[1][:, 1].tolist() == [1.0, 2.0]
    before = counts()
    f.write_text("t,x1\n0,1\n0.1,3\n")                      # same name, new content
    assert store.csv(f)[1][:, 1].tolist() == [1.0, 3.0] and _delta(before)["parsed"] == 1
    npy = store.paths(file_digest(f))[0]
    npy.write_bytes(npy.read_bytes()[:100])                 # a truncated entry (a crash, a full disk)
    assert store.csv(f)[1][:, 1].tolist() == [1.0, 3.0] and _delta(before)["parsed"] == 2


WRITER = """
import sys, time
from pathlib import Path
from kexp.data.parsed import ParsedStore, counts
go = Path(sys.argv[3])
while not go.exists():
    time.sleep(0.001)
header, values = ParsedStore(sys.argv[2]).csv(Path(sys.argv[1]))
print(counts()["parsed"], values.shape[0], float(values[-1, 1]))
"""


def test_concurrent_writers_of_one_entry_leave_a_whole_entry(tmp_path):
    """Two processes parse the same file into one folder at the same moment: each writes its own temporary file
    and renames it into place, so both read a whole entry, it equals a fresh parse and no temporary is left."""
    f = tmp_path / "big.csv"
    rows = np.column_stack([np.arange(60000) * 0.01, np.sin(np.arange(60000))])
    f.write_text("t,x1\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in rows))
    cache, go = tmp_path / "c", tmp_path / "go"
    procs = [subprocess.Popen([sys.executable, "-c", WRITER, str(f), str(cache), str(go)], stdout=subprocess.PIPE,
                              text=True) for _ in range(2)]
    go.touch()
    outs = [p.communicate(timeout=300)[0].split() for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert all(o[1:] == ["60000", repr(float(rows[-1, 1]))] for o in outs)
    assert _same_bits(ParsedStore(cache).csv(f)[1], read_csv(f)[1])
    assert sorted(p.suffix for p in cache.iterdir()) == [".json", ".npy"]


MALFORMED = [
    b"t,x1,x2\n0,1,2\n0.01,1.31o,2\n",
    b"t,x1,x2\n0,1,2\n0.01,0x1p-1,2\n",
    b"t,x1,x2\n0,1,2\n0.01,inf,2\n",
    b"t,x1,x2\n0,1,2\n0.01,1e31,2\n",
    b"t,x1,x2\n0,1,2\n0.01,1,2,3\n",
    b"t,x1,x2\n0,1,2\n,1,2\n",
    b"t,x1,x2\n0,1,2\n0.01,\xe9,2\n",
    b"t,x1,x2\n0,1,2\n0.01,1\x00,2\n",
    b"t,x1,x2\n0,1,2\r0.01,1,2\n",
    b"t,x1,x1\n0,1,2\n",
    b"\n\n",
    b"t,x1,x2\n" + b"0,1,2\n" * 40 + b"0," + b"1" * (70 << 10) + b",2\n",
]


@pytest.mark.parametrize("content", MALFORMED, ids=range(len(MALFORMED)))
@pytest.mark.parametrize("block", [1 << 20, 13])
def test_malformed_files_give_the_strict_reader_s_one_line_message(tmp_path, monkeypatch, content, block):
    monkeypatch.setattr(parsed, "BLOCK_BYTES", block)
    f = tmp_path / "bad.csv"
    f.write_bytes(content)
    with pytest.raises(DataError) as old:
        read_csv(f)
    with pytest.raises(DataError) as new:
        parse_csv_to_npy(f, tmp_path / "out.npy")
    assert str(new.value) == str(old.value) and "\n" not in str(new.value) and str(f) in str(new.value)
    store = ParsedStore(tmp_path / "c")
    with pytest.raises(DataError) as via_store:
        store.csv(f)
    assert str(via_store.value) == str(old.value)
    assert not list((tmp_path / "c").glob("*"))   # nothing half-written is left behind


def test_an_unwritable_cache_folder_warns_once_and_loses_nothing(tmp_path):
    folder = _runs(tmp_path / "runs", 3)
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    with pytest.warns(RuntimeWarning, match="cannot write there") as caught:
        src = open_runs(folder, parsed_dir=blocker / "parsed", **KW)
        model = identify(VDP, src, Monomials(2, 3), IdentifyConfig())
    assert len([w for w in caught if "parsed-data cache" in str(w.message)]) == 1
    ref = identify(VDP, open_runs(folder, parsed_dir=tmp_path / "ok", **KW), Monomials(2, 3), IdentifyConfig())
    assert _same_bits(model.Lambda, ref.Lambda) and _same_bits(model.C, ref.C)


def test_the_app_parses_into_the_cache_folder_s_parsed_subfolder(tmp_path):
    assert parsed_dir({"dir": str(tmp_path), "enabled": True}) == tmp_path / "parsed"
    assert parsed_dir({"dir": str(tmp_path), "enabled": False}) is None and parsed_dir(None) is None
    folder = _runs(tmp_path / "runs", 2)
    cfg = DataConfig(T=1.0, excitation=None, source=DataSource(kind="files", path=str(folder)))
    before = counts()
    read_data_files(VDP, cfg, {"dir": str(tmp_path / "cache")}).to_dataset()
    read_data_files(VDP, cfg, {"dir": str(tmp_path / "cache")}).to_dataset()   # the next job of a sweep
    assert _delta(before)["parsed"] == 2
    assert len(list((tmp_path / "cache" / "parsed").glob("csv-*-v1.npy"))) == 2


def test_parsing_memory_does_not_grow_with_the_row_count(tmp_path):
    """tracemalloc's peak while parsing 40 000 and 320 000 rows (about 1.2 and 9.7 MB of text): the same few
    blocks, not the text (the strict reader holds every value as a Python float list first)."""
    peaks = []
    for rows in (40000, 320000):
        f = tmp_path / f"r{rows}.csv"
        k = np.arange(rows)
        f.write_text("t,x1,x2\n" + "".join(f"{float(a)!r},{float(b)!r},{c}\n" for a, b, c in zip(k * 0.01, np.sin(k), k % 7)))
        tracemalloc.start()
        parse_csv_to_npy(f, tmp_path / f"r{rows}.npy")
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert np.load(tmp_path / f"r{rows}.npy").shape == (rows, 3)
    assert peaks[1] < 1.5 * peaks[0] and peaks[1] < 0.5 * f.stat().st_size, peaks
