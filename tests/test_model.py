import json

import numpy as np
import pytest

from kexp.data import Box, Circle, DataConfig, collect
from kexp.dictionary import Monomials
from kexp.errors import ModelFileError
from kexp.identify import FORMAT_VERSION, KoopmanBilinearModel, identify
from kexp.systems import SlowManifold, VanDerPol


@pytest.fixture(scope="module")
def vdp_model():
    s = VanDerPol()
    return identify(s, collect(s, Circle(30, 2.0), DataConfig(T=3.0)), Monomials(2, 4))


def test_save_load_round_trip(tmp_path, vdp_model):
    path = vdp_model.save(tmp_path / "m.npz")
    back = KoopmanBilinearModel.load(path)
    assert back == vdp_model  # all arrays, dictionary, dt, names
    x = np.random.default_rng(0).uniform(-1, 1, (10, 2))
    assert np.array_equal(back.lift(x), vdp_model.lift(x))
    assert back.report["prediction_error"] == vdp_model.report["prediction_error"]
    with np.load(path, allow_pickle=False) as f:  # plain npz, no pickled objects
        assert json.loads(str(f["meta"]))["version"] == FORMAT_VERSION


def test_load_errors_say_what_to_do(tmp_path, vdp_model):
    with pytest.raises(ModelFileError, match="does not exist"):
        KoopmanBilinearModel.load(tmp_path / "nope.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file")
    with pytest.raises(ModelFileError, match="re-run identification"):
        KoopmanBilinearModel.load(bad)
    path = vdp_model.save(tmp_path / "m.npz")
    with np.load(path, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    meta = json.loads(str(arrays["meta"]))
    meta["version"] = FORMAT_VERSION + 1
    arrays["meta"] = np.array(json.dumps(meta))
    old = tmp_path / "old.npz"
    np.savez(old, **arrays)
    with pytest.raises(ModelFileError, match=f"version {FORMAT_VERSION + 1}"):
        KoopmanBilinearModel.load(old)


def test_truncated_or_corrupt_model_file_is_a_model_file_error(tmp_path, vdp_model):
    """A file cut short (a killed copy, a full disk) or with a flipped byte: ModelFileError, not BadZipFile."""
    data = vdp_model.save(tmp_path / "m.npz").read_bytes()
    cut = tmp_path / "cut.npz"
    for n in (1, 4, 30, len(data) // 3, len(data) // 2, len(data) - 22, len(data) - 1):  # 4: the zip magic 'PK..'
        cut.write_bytes(data[:n])
        with pytest.raises(ModelFileError, match="is not a readable kexp model .*re-run identification"):
            KoopmanBilinearModel.load(cut)
    # a flipped byte inside the first array's data: the zip's CRC check fails
    first = data.index(b"\x93NUMPY") + 200
    cut.write_bytes(data[:first] + bytes([data[first] ^ 0xFF]) + data[first + 1:])
    with pytest.raises(ModelFileError, match="Bad CRC-32"):
        KoopmanBilinearModel.load(cut)


def test_model_is_frozen(vdp_model):
    with pytest.raises(ValueError):
        vdp_model.Lambda[0, 0] = 1.0
    with pytest.raises(Exception):
        vdp_model.dt = 0.1


def test_predict_shapes_and_input_effect(vdp_model):
    x0 = np.array([0.5, -0.5])
    xf, zf = vdp_model.predict(x0, np.zeros((50, 1)))
    xu, _ = vdp_model.predict(x0, np.ones(50))
    assert xf.shape == (51, 2) and zf.shape == (51, vdp_model.k)
    assert np.allclose(xf[0], x0, atol=1e-6)
    assert np.linalg.norm(xu[-1] - xf[-1]) > 0.1  # the input moves the state


def test_summary_mentions_key_facts(vdp_model):
    text = vdp_model.summary()
    for needle in ("cond(Φ_X)", "Assumption 1", "prediction error", "λ (continuous)", "constant eigenfunction"):
        assert needle in text


def test_summary_table_rows_are_the_model_s_numbers(vdp_model):
    """One row per eigenvalue block: its first coordinate j, |λ̃| the discrete eigenvalue's modulus, the
    residual, and the input's gain on coordinate j, ‖B[:, j, :]‖ (the row: how z drives ż_j), as printed."""
    m = vdp_model
    lines = m.summary().splitlines()
    rows = lines[next(i for i, ln in enumerate(lines) if "λ (continuous)" in ln) + 1:]
    assert len(rows) == len(np.unique(m.block))
    seen = []
    for row in rows:
        tok = row.split()
        j = int(tok[0])
        seen.append(m.block[j])
        assert tok[-3] == f"{abs(m.discrete[j]):.5f}" and tok[-2] == f"{m.residual[j]:.2e}"
        assert tok[-1] == f"{np.linalg.norm(m.B[:, j, :]):.3g}"
    assert sorted(seen) == sorted(np.unique(m.block))
    # the columns are not interchangeable on this model: the check above can tell row from column, λ̃ from λ
    assert not np.allclose(np.linalg.norm(m.B[0], axis=1), np.linalg.norm(m.B[0], axis=0), rtol=1e-3)
    assert not np.allclose(np.abs(m.discrete), np.abs(m.eigenvalues), rtol=1e-3)


def test_predict_tracks_true_system_for_short_horizon():
    from kexp.data import integrate
    s = SlowManifold()
    model = identify(s, collect(s, Box(20, -1.0, 1.0), DataConfig(T=2.0)), Monomials(2, 2, weights=(1, 2)))
    u = np.sin(np.arange(200) * 0.05)[:, None]
    xhat, _ = model.predict([0.3, 0.8], u)
    truth = integrate(s, np.array([[0.3, 0.8]]), np.arange(201) * 0.01, u[None])[0]
    assert np.max(np.abs(xhat - truth)) < 1e-7
