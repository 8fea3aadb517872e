"""McapFile writes byte-for-byte what mcap 1.6's Writer (zstd chunks) writes for the same calls: random message
streams (several channels, empty payloads, flushes, chunk overflows, out-of-order log times), an empty file, a
file flushed and never finished; the files read back with mcap's reader."""
import io
import json

import numpy as np
import pytest
import zstandard
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import CompressionType, Writer

from kexp.recording.mcap_file import ZSTD_LEVEL, McapFile


class Both:
    """Drives mcap's Writer and McapFile (synchronous, and with its compression thread) with the same calls,
    each into its own byte buffer."""

    def __init__(self, chunk_size=1 << 20):
        self.ref_io, self.ours_io, self.thread_io = io.BytesIO(), io.BytesIO(), io.BytesIO()
        self.ref = Writer(self.ref_io, compression=CompressionType.ZSTD, chunk_size=chunk_size)
        self.ours = [McapFile(self.ours_io, chunk_size=chunk_size),
                     McapFile(self.thread_io, chunk_size=chunk_size, thread=True)]
        for w in [self.ref] + self.ours:
            w.start(profile="", library="kexp-test/1")

    def schema(self, name, data):
        sid = self.ref.register_schema(name=name, encoding="jsonschema", data=data)
        assert all(w.register_schema(name=name, encoding="jsonschema", data=data) == sid for w in self.ours)
        return sid

    def channel(self, topic, schema_id, metadata=None):
        cid = self.ref.register_channel(topic=topic, message_encoding="json", schema_id=schema_id,
                                        metadata=metadata or {})
        assert all(w.register_channel(topic=topic, message_encoding="json", schema_id=schema_id,
                                      metadata=metadata or {}) == cid for w in self.ours)
        return cid

    def messages(self, msgs):
        for w in self.ours:
            w.add_messages(msgs)
        for channel, seq, log_time, publish_time, data in msgs:
            self.ref.add_message(channel_id=channel, log_time=log_time, data=data, publish_time=publish_time,
                                 sequence=seq)

    def flush(self):
        for w in [self.ref] + self.ours:
            w.flush()

    def finish(self):
        for w in [self.ref] + self.ours:
            w.finish()

    def same(self):
        self.ours[1].wait()
        ref, ours, threaded = self.ref_io.getvalue(), self.ours_io.getvalue(), self.thread_io.getvalue()
        assert len(ours) == len(ref)
        assert ours == ref
        assert threaded == ref
        return ours


def _random_stream(both, rng, n_messages, max_size, n_channels=4, flush_p=0.3):
    """Schemas and channels, then batches of messages with random channels, sizes (empty included), log times
    (mostly rising, sometimes back in time) and flushes between batches."""
    ids = []
    for i in range(n_channels):
        sid = both.schema(f"kexp.S{i}", json.dumps({"title": f"S{i}", "i": i}).encode())
        ids.append(both.channel(f"/topic{i}", sid, {"k": "v" * i} if i % 2 else None))
    t, seqs, sent = 10_000, [0] * len(ids), []
    while len(sent) < n_messages:
        batch = []
        for _ in range(int(rng.integers(1, 60))):
            c = int(rng.integers(len(ids)))
            t += int(rng.integers(0, 10_000_000))
            log_time = t - int(rng.integers(0, 50_000_000)) if rng.random() < 0.1 else t
            size = 0 if rng.random() < 0.1 else int(rng.integers(1, max_size))
            data = bytes(rng.integers(0, 256, size, dtype=np.uint8)) if rng.random() < 0.3 else \
                json.dumps({"t": log_time, "v": rng.normal(size=size // 20).tolist()}).encode()
            log_time = max(log_time, 0)
            batch.append((ids[c], seqs[c], log_time, log_time + 5 if rng.random() < 0.5 else log_time, data))
            seqs[c] += 1
        both.messages(batch)
        sent += batch
        if rng.random() < flush_p:
            both.flush()
        if rng.random() < flush_p / 6:
            both.flush()                 # a flush with nothing open
    return sent


@pytest.mark.parametrize("seed", range(4))
def test_random_streams_are_byte_identical_to_mcaps_writer(seed):
    """~2 MB in ~400-byte messages, rarely flushed: the default 1 MiB chunk overflows at least once."""
    rng = np.random.default_rng(seed)
    both = Both()
    sent = _random_stream(both, rng, 5000, 800, flush_p=0.003)
    both.finish()
    data = both.same()
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert len(summary.chunk_indexes) >= 2
    assert any(ci.uncompressed_size > 1 << 20 for ci in summary.chunk_indexes)
    stats = summary.statistics
    assert stats.message_count == len(sent) and stats.chunk_count == len(summary.chunk_indexes)
    assert stats.message_start_time == min(m[2] for m in sent)
    assert stats.message_end_time == max(m[2] for m in sent)
    assert sum(stats.channel_message_counts.values()) == len(sent)
    got = [(c.id, m.sequence, m.log_time, m.publish_time, m.data)
           for _, c, m in reader.iter_messages(log_time_order=False)]
    assert got == sent


@pytest.mark.parametrize("chunk_size", [1, 300, 5000])
def test_small_chunks_split_where_mcaps_do(chunk_size):
    """Chunk sizes below one message (every message its own chunk; the schemas alone overflow the first) up to
    a few dozen messages per chunk; a schema and a channel registered between messages."""
    rng = np.random.default_rng(chunk_size)
    both = Both(chunk_size)
    sent = _random_stream(both, rng, 600, 300, n_channels=2)
    sid = both.schema("late", b"{}")
    cid = both.channel("/late", sid)
    both.messages([(cid, 0, 5, 5, b"late"), (1, 999, 3, 3, b"")])
    both.flush()
    both.schema("after the last message", b"{}")  # waits in an open chunk without messages: never in the data
    both.finish()
    data = both.same()
    assert make_reader(io.BytesIO(data)).get_summary().statistics.message_count == len(sent) + 2


def test_an_empty_file_and_one_without_channels():
    both = Both()
    both.finish()
    both.same()
    both = Both()
    both.schema("s", b"{}")
    both.channel("/a", 1)
    both.flush()
    both.finish()
    summary = make_reader(io.BytesIO(both.same())).get_summary()
    assert summary.statistics.message_count == 0 and not summary.chunk_indexes and len(summary.channels) == 1


def test_a_flushed_file_that_is_never_finished():
    """RunLogger.abandon: flush, then close without the summary section."""
    rng = np.random.default_rng(7)
    both = Both()
    sent = _random_stream(both, rng, 300, 500)
    both.flush()
    data = both.same()
    got = []
    with pytest.raises(EndOfFile):   # no summary, no footer: read message by message up to the end
        for _, _, m in NonSeekingReader(io.BytesIO(data)).iter_messages(log_time_order=False):
            got.append(m.data)
    assert got == [m[4] for m in sent]


def test_a_reused_compressor_writes_what_a_fresh_one_does():
    """mcap calls zstandard.compress (a new compressor per chunk); McapFile keeps one."""
    rng = np.random.default_rng(3)
    cctx = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
    for size in (0, 1, 100, 10_000, 300_000, 2_000_000, 50_000):
        data = json.dumps(rng.normal(size=size // 20).tolist()).encode()[:size]
        assert cctx.compress(data) == zstandard.compress(data)


def test_a_negative_log_time_raises_like_mcaps():
    import struct
    for thread in (False, True):
        f = McapFile(io.BytesIO(), thread=thread)
        f.start()
        with pytest.raises(struct.error):
            f.add_messages([(1, 0, -1, 0, b"")])


class _FailingStream(io.BytesIO):
    def __init__(self, fail_after):
        super().__init__()
        self.fail_after = fail_after

    def write(self, data):
        if self.tell() + len(data) > self.fail_after:
            raise OSError("disk full")
        return super().write(data)


def test_an_error_on_the_compression_thread_is_raised_in_the_callers_thread():
    """A failed write on the thread: the next call raises it, every later one too, and nothing more is written."""
    f = McapFile(_FailingStream(2000), chunk_size=1000, thread=True)
    f.start()
    f.register_channel("/a", "json", 0)
    with pytest.raises(OSError, match="disk full"):
        for k in range(100):                      # each batch closes a chunk: the thread writes it
            f.add_messages([(1, k, k, k, b"x" * 600)])
        f.wait()
    with pytest.raises(OSError, match="disk full"):
        f.finish()
    f.stop()
    assert f._stream.tell() <= 2000


# -- RunLogger: the whole run log, against the path it replaced (mcap's Writer, the earlier log_step) -----------

class _McapWriter:
    """McapFile's interface on mcap's Writer, making the calls the earlier RunLogger made."""

    def __init__(self, stream, chunk_size, thread):
        self._w = Writer(stream, compression=CompressionType.ZSTD, chunk_size=chunk_size)
        self.start, self.register_schema = self._w.start, self._w.register_schema
        self.register_channel, self.flush, self.finish = self._w.register_channel, self._w.flush, self._w.finish

    def wait(self):
        pass

    def stop(self):
        pass

    def add_messages(self, messages):
        for channel, seq, log_time, publish_time, data in messages:
            self._w.add_message(channel_id=channel, log_time=log_time, publish_time=publish_time, data=data,
                                sequence=seq)


def _reference_logger(path, monkeypatch, **kw):
    """A RunLogger framing with mcap's Writer and logging steps as the earlier code did (its log_step verbatim)."""
    from kexp.recording import writer

    class Reference(writer.RunLogger):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self._next_flush = self.flush_every      # the earlier flush rule's own state (not FlushClock's)

        def log_step(self, rec, control_step=None, model=None) -> None:
            t = float(rec.t)
            self.write("/step", t, {
                "k": int(rec.k), "t": t, "x": rec.x.tolist(),
                "x_meas": (rec.x if getattr(rec, "x_meas", None) is None else rec.x_meas).tolist(),
                "z": np.asarray(rec.z).tolist(), "u": rec.u.tolist(),
                "w": (np.zeros_like(rec.u) if getattr(rec, "w", None) is None else np.asarray(rec.w)).tolist(),
                "V": float(rec.V), "Vdot": float(rec.Vdot), "region": rec.region, "active": rec.active,
                "binds": bool(rec.binds), "slack": float(rec.slack), "status": rec.status,
                "qp_status": rec.qp_status, "iterations": int(rec.iterations),
                "qp_iterations": int(rec.qp_iterations), "fallback": bool(rec.fallback), "reason": rec.reason})
            self.write("/timing", t, {"k": int(rec.k), "t": t, "solve_time": float(rec.solve_time)})
            if (self.prediction_every and control_step is not None and control_step.predicted is not None
                    and model is not None and rec.k % self.prediction_every == 0):
                Z = control_step.predicted
                self.write("/prediction", rec.t, {"k": rec.k, "t": rec.t,
                                                  "t_pred": rec.t + model.dt * np.arange(len(Z)),
                                                  "x_pred": model.to_state(Z)})
            if rec.t + 1e-12 >= self._next_flush:
                self._flush()
                self._next_flush += self.flush_every

    with monkeypatch.context() as m:
        m.setattr(writer, "McapFile", _McapWriter)
        return Reference(path, **kw)


@pytest.fixture(scope="module")
def run(short_lmpc_run):
    """The short LMPC closed loop of conftest's ``short_lmpc_run``, and records that vary what a step holds: a
    disturbance w, no separate x_meas, NaN and infinite values, a float32 lifted state, a list z."""
    from dataclasses import replace

    model, clf, result, steps = short_lmpc_run
    steps = list(steps)
    last, st = steps[-1]
    rng = np.random.default_rng(1)
    for i, change in enumerate([{"w": rng.normal(size=1)}, {"x_meas": None}, {"V": np.nan, "Vdot": np.inf},
                                {"z": last.z.astype(np.float32)}, {"z": list(last.z)},
                                {"x": np.array([np.nan, -0.0]), "u": np.array([1e300])}]):
        steps.append((replace(last, k=last.k + 1 + i, t=last.t + 0.01 * (1 + i), **change), st))
    return model, clf, result, steps


def _log_run(lg, run):
    model, clf, result, steps = run
    with lg:
        lg.log_config({"a": 1, "nested": {"b": [1.5, None]}}, "h")
        lg.log_model(model)
        lg.log_clf(clf)
        for rec, st in steps:
            lg.log_step(rec, st, model)
        lg.log_open_loop(result.t[:50], result.x[:50])
        lg.log_summary(float(result.t[-1]), result.status, "", {"cost": result.metrics.cost}, True,
                       {"noise": {"sigma": 0.0}, "plant": {}})
        lg.log_run_info(float(result.t[-1]), {"kexp": "0"}, {"wall_time_s": 1.0}, None)
    return lg.path.read_bytes()


@pytest.mark.parametrize("background,compress_thread", [(False, True), (False, False), (True, True)])
def test_a_run_log_is_byte_identical_to_the_earlier_writers(tmp_path, monkeypatch, run, background,
                                                             compress_thread):
    from kexp.recording.writer import RunLogger
    kw = dict(prediction_every=10, flush_every=0.5)
    ref = _log_run(_reference_logger(tmp_path / "ref.mcap", monkeypatch, **kw), run)
    new = _log_run(RunLogger(tmp_path / "new.mcap", background=background, compress_thread=compress_thread, **kw),
                   run)
    assert len(new) > 10_000 and new == ref
    summary = make_reader(io.BytesIO(new)).get_summary()
    step_id = next(c.id for c in summary.channels.values() if c.topic == "/step")
    assert summary.statistics.channel_message_counts[step_id] == len(run[3])
    assert len(summary.chunk_indexes) == 5          # flushed at 0.5, 1, 1.5 and 2 s, and at close


def test_an_abandoned_run_log_is_byte_identical_to_the_earlier_writers(tmp_path, monkeypatch, run):
    from kexp.recording.writer import RunLogger
    model, _, _, steps = run
    logs = []
    for lg in (_reference_logger(tmp_path / "ref.mcap", monkeypatch, prediction_every=10, flush_every=0.3),
               RunLogger(tmp_path / "new.mcap", prediction_every=10, flush_every=0.3)):
        for rec, st in steps[:77]:
            lg.log_step(rec, st, model)
        lg.abandon()
        logs.append(lg.path.read_bytes())
    assert len(logs[1]) > 5_000 and logs[1] == logs[0]
