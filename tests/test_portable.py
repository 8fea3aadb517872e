"""The golden policy across machines: the portable diff policy holds under real variation of the linear-algebra
path (OpenBLAS kernels and thread counts, each in its own process), catches real changes, and compares the model
by what it does rather than by entries that depend on the eigen-coordinates."""
import json
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from kexp.app import golden
from kexp.recording import copy_log, diff_logs
from kexp.recording.diff import main as diff_main

from cli import console_script

GOLDEN = golden.RECORDINGS / "paper_pendulum.mcap"   # the worst-conditioned shipped case: cond(Phi_X) = 1.5e6

RECORD = """
import json, sys
from pathlib import Path
from threadpoolctl import threadpool_info
from kexp.app.golden import record
record(sys.argv[1], Path(sys.argv[2]))
blas = [i for i in threadpool_info() if i["user_api"] == "blas" and ("numpy" in i["filepath"] or "scipy" in i["filepath"])]
print(json.dumps({"arch": sorted({i.get("architecture") for i in blas}), "threads": sorted({i["num_threads"] for i in blas})}))
"""


def _cpu_flags() -> set[str]:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def _record(tmp_path, name, threads, coretype=None):
    """Record golden ``name`` in a fresh process with the given BLAS threads and OpenBLAS kernel."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OPENBLAS_", "OMP_", "MKL_"))}
    env["OPENBLAS_NUM_THREADS"] = str(threads)
    if coretype:
        env["OPENBLAS_CORETYPE"] = coretype
    out = tmp_path / f"{name}_{coretype or 'default'}_{threads}.mcap"
    proc = subprocess.run([sys.executable, "-c", RECORD, name, str(out)], env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out, json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def default_runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("threads")
    return {t: _record(tmp, "paper_pendulum", t) for t in (1, 2)}


def test_blas_thread_count_changes_no_deterministic_channel(default_runs):
    """Identification, CLF and closed loop pin BLAS to one thread: 1 and 2 threads give identical logs."""
    (one, info1), (two, info2) = default_runs[1], default_runs[2]
    assert info1["threads"] == [1] and info2["threads"] == [2]        # the setting reached OpenBLAS
    res = diff_logs(one, two)
    assert res.equal, res.report()


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="OpenBLAS x86 kernels")
@pytest.mark.parametrize("coretype,flag", [("Prescott", "pni"), ("Sandybridge", "avx")])
def test_golden_policy_holds_under_another_blas_kernel(tmp_path, default_runs, coretype, flag):
    """Another CPU's kernels (forced with OPENBLAS_CORETYPE, in a fresh process, 2 threads): the run differs
    from this machine's in the last bits (so exact is the wrong policy for a golden) but agrees with the
    committed golden under the portable policy, with at least 10x headroom on every channel."""
    if flag not in _cpu_flags():
        pytest.skip(f"this CPU lacks {flag}")
    own, own_info = default_runs[1]
    new, info = _record(tmp_path, "paper_pendulum", 2, coretype)
    if info["arch"] == own_info["arch"]:
        pytest.skip(f"{coretype} is this machine's own kernel ({info['arch']})")
    assert not diff_logs(own, new).equal                              # a real variation of the numbers
    res = diff_logs(GOLDEN, new, policy="portable")
    assert res.equal, res.report()
    assert max(res.usage.values()) < 0.1, res.usage


def _change_basis(seed: int):
    """An edit that re-expresses the model in other eigen-coordinates z' = S z (S random, well conditioned):
    Λ' = SΛS⁻¹, B' = SBS⁻¹, b' = Sb, C' = CS⁻¹, P' = S⁻ᵀPS⁻¹.  The model does exactly the same."""
    state = {}

    def edit(topic, p):
        if topic == "/model":
            k = len(p["Lambda"])
            rng = np.random.default_rng(seed)
            S = np.eye(k)[rng.permutation(k)] * rng.choice([-1.0, 1.0], k)[:, None] * rng.uniform(0.5, 2.0, k)[:, None]
            S = S + 0.05 * rng.normal(size=(k, k))
            Si = np.linalg.inv(S)
            state["S"], state["Si"] = S, Si
            p["Lambda"] = (S @ np.array(p["Lambda"]) @ Si).tolist()
            p["B"] = [(S @ np.array(Bi) @ Si).tolist() for Bi in p["B"]]
            p["b"] = [(S @ np.array(bi)).tolist() for bi in p["b"]]
            p["C"] = (np.array(p["C"]) @ Si).tolist()
        elif topic == "/clf":
            Si = state["Si"]
            p["P"] = (Si.T @ np.array(p["P"]) @ Si).tolist()
        elif topic == "/step":
            p["z"] = (state["S"] @ np.array(p["z"])).tolist()
    return edit


def test_portable_compares_the_model_by_what_it_does(tmp_path):
    moved = tmp_path / "basis.mcap"
    copy_log(GOLDEN, moved, _change_basis(0))
    exact = diff_logs(GOLDEN, moved)
    assert not exact.equal and exact.first.channel == "/model" and exact.first.field.startswith("B")
    res = diff_logs(GOLDEN, moved, policy="portable")
    assert res.equal, res.report()
    assert res.usage["/model"] < 0.1                                  # predictions agree to rounding

    # the same model with one input-matrix entry wrong by 1e-3 of B's norm predicts differently
    wrong = tmp_path / "wrong_B.mcap"

    def perturb(topic, p):
        if topic == "/model":
            B = np.array(p["B"])
            i = np.unravel_index(np.argmax(np.abs(B[0])), B[0].shape)
            B[0][i] += 1e-3 * np.abs(B).max()
            p["B"] = B.tolist()
    copy_log(GOLDEN, wrong, perturb)
    res = diff_logs(GOLDEN, wrong, policy="portable")
    assert not res.equal and res.first.channel == "/model" and res.first.field.startswith("prediction"), res.report()

    # an eigenvalue moved by 1e-4 (in a model that otherwise predicts the same from x0) is caught as a set
    moved_eig = tmp_path / "eig.mcap"

    def shift(topic, p):
        if topic == "/model":
            p["eigenvalues_re"][3] += 1e-4
    copy_log(GOLDEN, moved_eig, shift)
    res = diff_logs(GOLDEN, moved_eig, policy="portable")
    assert not res.equal and res.first.field == "eigenvalues (as a set)", res.report()


@pytest.mark.parametrize("edit,channel,field", [
    (lambda t, p: p["u"].__setitem__(0, p["u"][0] + 1e-4) if t == "/step" and p["k"] == 57 else None,
     "/step", "u[0]"),
    (lambda t, p: p.update(binds=not p["binds"]) if t == "/step" and p["k"] == 120 else None, "/step", "binds"),
    (lambda t, p: p.update(iterations=p["iterations"] + 1) if t == "/step" and p["k"] == 3 else None,
     "/step", "iterations"),
    (lambda t, p: p["x"].__setitem__(1, p["x"][1] * (1 + 1e-4)) if t == "/step" and p["k"] == 199 else None,
     "/step", "x[1]"),
    (lambda t, p: p.update(r=p["r"] * (1 + 1e-5)) if t == "/clf" else None, "/clf", "r"),
    (lambda t, p: p["config"]["clf"].update(gamma=p["config"]["clf"]["gamma"] + 1e-9) if t == "/config" else None,
     "/config", "config.clf.gamma"),
    (lambda t, p: p["x"].__setitem__(0, p["x"][0] + 1e-8) if t == "/open_loop" and p["t"] > 1 else None,
     "/open_loop", "x[0]"),
])
def test_portable_catches_real_changes(tmp_path, edit, channel, field):
    changed = tmp_path / "changed.mcap"
    copy_log(GOLDEN, changed, edit)
    res = diff_logs(GOLDEN, changed, policy="portable")
    assert not res.equal and (res.first.channel, res.first.field) == (channel, field), res.report()


def test_portable_tolerates_rounding_but_exact_does_not(tmp_path):
    changed = tmp_path / "rounding.mcap"

    def edit(t, p):
        if t == "/step":
            p["u"] = [v * (1 + 1e-12) for v in p["u"]]
            p["V"] *= 1 + 1e-12
    copy_log(GOLDEN, changed, edit)
    assert not diff_logs(GOLDEN, changed).equal
    assert diff_logs(GOLDEN, changed, policy="portable").equal



def test_portable_bound_is_relative_to_the_field_s_largest_magnitude(tmp_path):
    """MODEL's rule: max |Δ| over a field ≤ 1e-9 + 1e-6·(the field's largest |entry| over the channel), not a
    typical one: x[1] of the last step moved by 0.9 of that bound is equal, by 1.1 of it is not."""
    from kexp.recording import read_log
    x = np.abs([m["x"] for m in read_log(GOLDEN).messages("/step")])
    bound = 1e-9 + 1e-6 * x.max()
    assert 0.9 * bound > 1e-9 + 1e-6 * x.mean(axis=1).max()   # a scale from each message's mean entry refuses it
    last = len(x) - 1

    def move(by):
        return lambda t, p: p["x"].__setitem__(1, p["x"][1] + by) if t == "/step" and p["k"] == last else None
    for factor, equal in ((0.9, True), (1.1, False)):
        moved = tmp_path / f"moved{factor}.mcap"
        copy_log(GOLDEN, moved, move(factor * bound))
        res = diff_logs(GOLDEN, moved, policy="portable")
        assert res.equal is equal, res.report()


def test_cli_policy_and_a_closed_pipe(tmp_path, capsys):
    assert diff_main(["--policy", "portable", str(GOLDEN), str(GOLDEN)]) == 0
    assert "logs are equal (portable)" in capsys.readouterr().out
    assert diff_main(["--policy", "portable", "--rtol", "1e-3", str(GOLDEN), str(GOLDEN)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("kexp-diff: error: the portable policy") and "\n" not in err
    other = golden.RECORDINGS / "paper_vanderpol.mcap"
    cmd = f"{shlex.quote(console_script('kexp-diff'))} {shlex.quote(str(GOLDEN))} {shlex.quote(str(other))} | head -1"
    proc = subprocess.run(cmd, shell=True, capture_output=True, text=True)
    assert proc.stdout.startswith("first divergence") and proc.stderr == "", proc.stderr


def test_golden_cli_refuses_bad_names_and_folders_before_any_run(tmp_path, capsys):
    """Checked before the first recording's 3 s of work (an unmakeable -o failed after it, with a traceback)."""
    from kexp.app.golden import main as golden_main
    afile = tmp_path / "afile"
    afile.write_text("")
    assert golden_main(["nope", "-o", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("golden: error: unknown recording 'nope'; valid: ")
    assert golden_main(["paper_vanderpol", "-o", str(afile / "sub")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"golden: error: -o {afile / 'sub'}: cannot make the folder (")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
