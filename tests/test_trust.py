"""The trust model (README, Reliability): what kexp refuses to load although a tool it builds on would — Hydra's
--experimental-rerun unpickles a file — and data a dictionary would overflow on, refused in one line."""
import pickle
import subprocess

import numpy as np

from cli import console_script


class _Touch:
    """Unpickling this creates ``path``: the side effect any pickle can have."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return open, (self.path, "w")


def test_experimental_rerun_is_refused_without_loading_the_pickle(tmp_path):
    marker = tmp_path / "ran"
    payload = tmp_path / "config.pickle"
    payload.write_bytes(pickle.dumps(_Touch(marker)))
    pickle.loads(payload.read_bytes()).close()   # the payload does run when unpickled
    assert marker.exists()
    marker.unlink()
    proc = subprocess.run([console_script("kexp"), "--experimental-rerun", str(payload)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1, proc.stderr[-2000:]
    assert err[0].startswith(f"kexp: error: --experimental-rerun {payload}: Hydra loads that file with pickle")
    assert ".hydra/overrides.yaml" in err[0]
    assert not marker.exists() and proc.stdout == ""


def test_data_a_high_degree_dictionary_would_overflow_on_is_refused_in_one_line(tmp_path):
    """Values at the files' limit (1e30) pass the reader; monomials up to degree 8 of them reach 1e240, and their
    Gram sums overflow: one line naming the state and what to change, before identification (was a traceback)."""
    runs = tmp_path / "runs"
    runs.mkdir()
    t = np.arange(101) * 0.01
    for i in range(3):
        x = np.column_stack([np.cos(t + i), np.sin(t + i)])
        if i == 1:
            x[40, 1] = 1e30
        lines = ["t,x1,x2"] + [f"{float(a)!r},{float(b)!r},{float(c)!r}" for a, b, c in zip(t, x[:, 0], x[:, 1])]
        (runs / f"r{i}.csv").write_text("\n".join(lines) + "\n")
    args = ["data.source.kind=files", f"data.source.path={runs}", "dictionary.degree=8", "identification.holdout=0",
            "logging.rrd=false", "logging.progress=false", "cache.enabled=false", "sim.allow_outside_data=true",
            f"hydra.run.dir={tmp_path / 'out'}"]
    proc = subprocess.run([console_script("kexp"), *args], capture_output=True, text=True, timeout=300)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert err[0].startswith("kexp: error: ") and "the data reach |x2| = 1e+30" in err[0], err[0]
    assert "dictionary.degree=8 reach 1e240" in err[0] and "dictionary.scale=auto" in err[0], err[0]
