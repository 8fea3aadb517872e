"""kexp.recording.steps: a flush's /step, /timing and /prediction messages encoded in one pass are byte for byte
what encoding each message on its own (encode, orjson with sorted keys) gives, for records of every kind a run or
a user can make: odd strings (the batch's cut mark, quotes, newlines, non-ASCII), non-finite and extreme floats,
numpy scalars, float32 vectors, a list z, and an int beyond 64 bits (the one-by-one path)."""
import numpy as np
import pytest

from kexp.recording.schema import encode
from kexp.recording.steps import (log_times, prediction_message, prediction_payload, step_messages, step_payload,
                                  timing_messages, timing_payload)
from kexp.recording.writer import _ns
from kexp.simulate import StepRecord

ODD = ['},{"V":', '"', "\\", "a\nb", "ü→∞", "", "},{\"k\":", "]}"]
FLOATS = [0.0, -0.0, 1e-7, 1e16, 5e-324, 1.7976931348623157e308, np.nan, np.inf, -np.inf, 0.1, 1 / 3, -2.5e-300]


def _record(rng, k, **change):
    n, m, kz = 2, 1, 21

    def pick():
        if rng.random() < 0.3:
            return FLOATS[rng.integers(len(FLOATS))]
        return float(rng.normal() * 10.0 ** rng.integers(-8, 8))

    fields = dict(k=k, t=0.01 * k, x=np.array([pick() for _ in range(n)]), z=np.array([pick() for _ in range(kz)]),
                  u=np.array([pick() for _ in range(m)]), V=pick(), Vdot=pick(), region=str(rng.choice(ODD)),
                  active=str(rng.choice(["21e", "21f", "none"])), binds=bool(rng.random() < 0.5), slack=pick(),
                  status="solved", qp_status=str(rng.choice(ODD)), iterations=int(rng.integers(0, 5)),
                  qp_iterations=int(rng.integers(0, 40)), solve_time=float(rng.random() * 1e-3),
                  fallback=bool(rng.random() < 0.1), reason=str(rng.choice(ODD)),
                  x_meas=None if rng.random() < 0.5 else np.array([pick() for _ in range(n)]),
                  w=None if rng.random() < 0.5 else np.array([pick() for _ in range(m)]))
    fields.update(change)
    return StepRecord(**fields)


def _old_step_json(rec) -> bytes:
    """The /step message as RunLogger wrote it before the batch (kexp 0.x, its _step_json verbatim)."""
    u = rec.u
    return encode({
        "k": int(rec.k), "t": float(rec.t), "x": rec.x.tolist(),
        "x_meas": (rec.x if rec.x_meas is None else rec.x_meas).tolist(), "z": np.asarray(rec.z).tolist(),
        "u": u.tolist(), "w": (np.zeros(u.shape, u.dtype) if rec.w is None else np.asarray(rec.w)).tolist(),
        "V": float(rec.V), "Vdot": float(rec.Vdot), "region": rec.region, "active": rec.active,
        "binds": bool(rec.binds), "slack": float(rec.slack), "status": rec.status, "qp_status": rec.qp_status,
        "iterations": int(rec.iterations), "qp_iterations": int(rec.qp_iterations),
        "fallback": bool(rec.fallback), "reason": rec.reason})


@pytest.fixture(scope="module")
def records():
    rng = np.random.default_rng(7)
    recs = [_record(rng, k) for k in range(300)]
    # numpy scalars, float32 and int vectors, a list z, a float32 u with its zero disturbance
    recs += [_record(rng, np.int64(300), V=np.float32(0.1), binds=np.bool_(True), iterations=np.int32(3)),
             _record(rng, 301, z=np.linspace(-1, 1, 21).astype(np.float32), x=np.array([1, 2])),
             _record(rng, 302, z=list(np.linspace(-1, 1, 21))),
             _record(rng, 303, u=np.array([0.25], np.float32), w=None),
             _record(rng, 304, slack=0, V=1)]   # ints where floats belong: written as floats
    return recs


def test_the_step_payload_keys_are_sorted_and_its_bytes_are_the_earlier_messages(records):
    for rec in records:
        assert list(step_payload(rec)) == sorted(step_payload(rec))
        assert list(timing_payload(rec)) == sorted(timing_payload(rec))
        assert encode(step_payload(rec)) == _old_step_json(rec)


@pytest.mark.parametrize("size", [0, 1, 2, 100, 305])
def test_a_batch_of_steps_is_byte_identical_to_one_message_at_a_time(records, size):
    batch = records[:size] if size <= 300 else records
    assert step_messages(batch) == [_old_step_json(r) for r in batch]
    assert timing_messages(batch) == [encode({"k": int(r.k), "t": float(r.t), "solve_time": float(r.solve_time)})
                                      for r in batch]
    assert log_times(batch) == [_ns(r.t) for r in batch]


def test_an_int_orjson_cannot_write_goes_one_message_at_a_time(records):
    """An int beyond 64 bits makes orjson refuse the whole batch; each message is then encoded on its own (the
    standard library writes the big int), the others unchanged."""
    from dataclasses import replace
    batch = list(records[:5]) + [replace(records[5], iterations=2 ** 70)]
    out = step_messages(batch)
    assert out[:5] == [_old_step_json(r) for r in batch[:5]]
    assert b'"iterations":1180591620717411303424' in out[5]


def test_log_times_round_half_to_even_as_round_does():
    ts = [0.5e-9, 1.5e-9, 2.5e-9, 0.01 * 7, 1234.5678901, 0.0, 10.0 - 1e-12]
    recs = [StepRecord(k=0, t=t, x=np.zeros(1), z=np.zeros(1), u=np.zeros(1), V=0.0, Vdot=0.0, region="",
                       active="", binds=False, slack=0.0, status="", qp_status="", iterations=0, qp_iterations=0,
                       solve_time=0.0, fallback=False, reason="") for t in ts]
    assert log_times(recs) == [int(round(float(t) * 1e9)) for t in ts]


class _Model:
    dt = 0.01

    def __init__(self, C):
        self.C = C

    def to_state(self, Z):
        return Z @ self.C.T


def test_a_prediction_message_is_the_generic_encoding(records):
    rng = np.random.default_rng(3)
    model = _Model(rng.normal(size=(2, 21)))
    for Z in (rng.normal(size=(101, 21)), np.where(rng.random((11, 21)) < 0.1, np.nan, rng.normal(size=(11, 21))),
              rng.normal(size=(5, 21)).astype(np.float32)):
        for rec in records[:3] + records[300:301]:
            assert prediction_message(rec, Z, model) == encode(prediction_payload(rec, Z, model))
    assert b"null" in prediction_message(records[0], np.full((3, 21), np.nan), model)
