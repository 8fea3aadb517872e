"""How much MCAP logging adds to a closed-loop run (Van der Pol, LMPC, 10 s = 1000 steps; --T for longer runs).

Runs the same closed loop without a log, with the per-step RunLogger (flush every simulated second), and with
the LMPC's predicted horizon logged every 20 steps (the default) or 10 steps too (an extra exact rollout each
time), with the chunks compressed in the loop's thread instead of McapFile's compression thread
(``RunLogger(compress_thread=False)``), with the writer thread (``RunLogger(background=True)``: each flush hands
the loop's records to the thread, which encodes and writes them while the loop runs on, holding the GIL but for
the loop's compiled kernels), and with the writer process (``ProcessRunLogger``, ``logging.writer=process``: at each
flush time, and with the run's last step (``last_step``, as the app passes it), the records are packed and handed
to a child process that encodes, frames and compresses them),
interleaved, and prints the median wall times and their ratio, and the median over the repeats of each run's
ratio to the no-log run of the same repeat (paired: the machine's slow drifts cancel).  Wall-time ratios between
runs carry the machine's noise (a few % on a shared 2-core VM, at times more than the logging), so the cost of
logging is also timed directly inside each run: the logger's start (opening the file; for the writer process
taking the child started ahead, at the run's start, as kexp's app does: ``process_log.prestart``, then the 0.3 s
a cached app run spends on its model, CLF and controller before the loop), the logging
callback and close() (with the writer thread: the hand-over and the wait for the thread's last batch; with the
compression thread: the wait for the last chunk; with the writer process: the wait for the child to finish the
file), plus the exact rollouts the LMPC makes only to log its prediction (kexp.control.lmpc's rollout and
rollout_poly, wrapped here; in RTI mode nothing else calls them), as a share of the no-log run time and, median
over the repeats, of the rest of its own run (a share the machine's drift between runs does not move).  The direct
measure of the thread modes does not see the threads' competition for the GIL and the cores; the wall-time
columns do.  One BLAS thread.  ``--breakdown N``: then N runs at the defaults with the logging's pieces timed one
by one (encoding, framing, chunk hand-over, close, rollouts), and N with the writer process (start, packing, the
pipe, close).
Logging also costs the loop indirectly: its encoding evicts the loop's data from the caches, and a writer thread
holds the GIL when the loop's kernels return.  So the time in the LMPC's compiled kernels (condense and the block
maps, which log nothing) is timed too, with the loop thread's CPU time: their growth over the no-log run is that
indirect cost.

    python benchmarks/logging_overhead.py [--repeat 7] [--T 10] [--breakdown 9]
"""
import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import contextlib  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import kexp.control.lmpc as lmpc_module  # noqa: E402
from kexp.clf import ClfConfig, synthesize_clf  # noqa: E402
from kexp.control import Lmpc, LmpcConfig, make_law  # noqa: E402
from kexp.data import Circle, DataConfig, collect  # noqa: E402
from kexp.dictionary import Monomials  # noqa: E402
from kexp.identify import identify  # noqa: E402
from kexp.recording.process_log import ProcessRunLogger  # noqa: E402
from kexp.recording.writer import RunLogger  # noqa: E402
from kexp.simulate import SimConfig, closed_loop  # noqa: E402
from kexp.systems import VanDerPol  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--T", type=float, default=10.0, help="simulated seconds per run (100 steps per second)")
    p.add_argument("--breakdown", type=int, default=0, metavar="N",
                   help="then N more runs at the defaults with the logging's pieces timed one by one")
    args = p.parse_args()
    s = VanDerPol()
    model = identify(s, collect(s, Circle(100, 2.5), DataConfig(T=10.0)), Monomials(2, 5))
    clf = synthesize_clf(model, ClfConfig())
    h = make_law("sontag", clf.lyap, -5.0, 5.0)
    x0 = np.array([0.7, -0.5])
    sim = SimConfig(T=args.T)
    # mode -> (prediction_every, writer thread, compression thread)
    every = {"no log": (0, False, True), "MCAP log": (0, False, True),
             "MCAP log + predictions every 20 steps (the default, what kexp runs)": (20, False, True),
             "MCAP log + predictions every 10 steps": (10, False, True),
             "MCAP log + predictions every 20 steps, chunks compressed in the loop's thread "
             "(RunLogger(compress_thread=False))": (20, False, False),
             "MCAP log + predictions every 20 steps, writer thread (RunLogger(background=True))": (20, True, True),
             "MCAP log + predictions every 20 steps, writer process (ProcessRunLogger)": (20, "process", True)}
    times = {mode: [] for mode in every}
    inside = {mode: [] for mode in times}     # seconds spent on logging inside the run
    spent = [0.0]
    kern = [0.0]        # seconds in the LMPC's compiled kernels (no logging in them: what logging does to them)
    cpu: dict = {mode: [] for mode in times}       # the loop thread's CPU time

    def timed(fn, acc):
        """``fn``, its time added to acc[0]."""
        def wrapper(*a):
            t = time.perf_counter()
            out = fn(*a)
            acc[0] += time.perf_counter() - t
            return out
        return wrapper

    lmpc_module.rollout = timed(lmpc_module.rollout, spent)
    lmpc_module.rollout_poly = timed(lmpc_module.rollout_poly, spent)
    lmpc_module.condense = timed(lmpc_module.condense, kern)
    lmpc_module.block_maps_poly = timed(lmpc_module.block_maps_poly, kern)
    kernels: dict = {mode: [] for mode in times}

    def logged(logger):
        def cb(rec, st):
            t = time.perf_counter()
            logger.log_step(rec, st, model)
            spent[0] += time.perf_counter() - t
        return cb

    with tempfile.TemporaryDirectory() as tmp:
        modes = list(times)
        for i in range(args.repeat):
            for mode in modes[i % len(modes):] + modes[: i % len(modes)]:  # rotate the order: no mode always first
                pred, background, compress_thread = every[mode]
                ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0, prediction_every=pred)
                spent[0] = kern[0] = 0.0
                if background == "process":
                    started_ahead()
                path = Path(tmp) / f"r{i}-{modes.index(mode)}.mcap"   # one file per run: a logger creates its own
                t0, c0 = time.perf_counter(), time.thread_time()    # the logger's start counts
                if mode == "no log":
                    logger = None
                elif background == "process":
                    logger = ProcessRunLogger(path, prediction_every=pred,
                                              last_step=(sim.n_steps - 1) * sim.dt)   # as the app passes it
                else:
                    logger = RunLogger(path, prediction_every=pred, background=background,
                                       compress_thread=compress_thread)
                cb = logged(logger) if logger else None
                spent[0] += time.perf_counter() - t0
                closed_loop(s, ctrl, x0, sim, model=model, lyap=clf.lyap, on_step=cb)
                if logger:
                    t1 = time.perf_counter()
                    logger.close()
                    spent[0] += time.perf_counter() - t1
                times[mode].append(time.perf_counter() - t0)
                cpu[mode].append(time.thread_time() - c0)
                inside[mode].append(spent[0])
                kernels[mode].append(kern[0])
    base = np.median(times["no log"])
    print(f"closed loop, Van der Pol, LMPC (RTI), {sim.n_steps} steps, {args.repeat} interleaved repeats "
          "(order rotated), one BLAS thread\n")
    print("| mode | median wall time [s] | min [s] | wall-time overhead vs no log | paired | logging time inside the "
          "run [ms] | per step [µs] | direct overhead | of its own run | loop thread CPU [s] | LMPC kernels [ms] | kernels, paired |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for mode, ts in times.items():
        med, ins = np.median(ts), np.median(inside[mode])
        # each run's logging against the rest of that run: the machine's drift between runs cancels
        own = np.median(np.array(inside[mode]) / (np.array(ts) - np.array(inside[mode])))
        paired = np.median(np.array(ts) / np.array(times["no log"]))   # each repeat against its own no-log run
        kpaired = np.median(np.array(kernels[mode]) / np.array(kernels["no log"]))
        print(f"| {mode} | {med:.3f} | {np.min(ts):.3f} | {100 * (med / base - 1):+.1f} % | "
              f"{100 * (paired - 1):+.1f} % | {1e3 * ins:.1f} | {1e6 * ins / sim.n_steps:.1f} | "
              f"{100 * ins / base:.1f} % | {100 * own:.1f} % | {np.median(cpu[mode]):.3f} | {1e3 * np.median(kernels[mode]):.1f} | "
              f"{100 * (kpaired - 1):+.1f} % |")
    if args.breakdown:
        breakdown(s, model, clf, h, x0, sim, args.breakdown)


def breakdown(s, model, clf, h, x0, sim, repeat):
    """Where the logging's time goes inside a run at the defaults: the pieces wrapped one by one (the wrappers'
    own cost, ~0.1 µs a call, included), medians over ``repeat`` runs, per step."""
    import kexp.recording.writer as writer_module
    from kexp.recording.mcap_file import McapFile

    acc: dict = {}

    def timed(name, fn):
        def wrapper(*a):
            t = time.perf_counter()
            out = fn(*a)
            acc[name] = acc.get(name, 0.0) + time.perf_counter() - t
            return out
        return wrapper

    pieces = [(writer_module, "step_messages", "encoding the /step messages (at the flushes and at close)"),
              (writer_module, "timing_messages", "encoding the /timing messages"),
              (writer_module, "prediction_message", "encoding the /prediction messages"),
              (McapFile, "add_messages", "framing the messages (McapFile.add_messages)"),
              (McapFile, "flush", "closing a chunk at a flush (hand-over to the compression thread)"),
              (McapFile, "wait", "close: waiting for the last chunk's compression (zstd level 3)"),
              (lmpc_module, "rollout_poly", "the LMPC's exact rollouts for the plans")]
    rows = timed_runs(s, model, clf, h, x0, sim, repeat, timed, acc, pieces,
                      lambda tmp, i: (RunLogger(tmp / f"b{i}.mcap", prediction_every=20), {}),
                      "log_step (all)", "close (all)")
    print_pieces(f"where the logging's time goes at the defaults, {repeat} runs, medians per step [µs]",
                 "per step [µs]", rows, 1e6 / sim.n_steps)
    process_breakdown(s, model, clf, h, x0, sim, repeat, timed, acc)


AHEAD = 0.3     # s: a cached app run's model, CLF and controller phases before its loop took 0.27 s (summary.json)


def started_ahead() -> None:
    """As kexp's app does for logging.writer=process: the writer process started at the run's start
    (process_log.prestart), its imports done while the app loads the model and CLF and builds the controller."""
    from kexp.recording import process_log
    process_log.prestart()
    time.sleep(AHEAD)


@contextlib.contextmanager
def patched(pieces, timed):
    """Each (owner, name, label) of ``pieces`` wrapped by ``timed(label, ·)`` inside the block, restored after."""
    saved = [(owner, name, getattr(owner, name)) for owner, name, _ in pieces]
    try:
        for owner, name, label in pieces:
            setattr(owner, name, timed(label, getattr(owner, name)))
        yield
    finally:
        for owner, name, fn in saved:
            setattr(owner, name, fn)


def timed_runs(s, model, clf, h, x0, sim, repeat, timed, acc, pieces, start, log_label, close_label):
    """``repeat`` closed loops at the defaults (plans every 20 steps) with ``pieces`` (:func:`patched`) and the
    logger's log_step and close timed into ``acc``; ``start(tmp, i)`` gives the logger and its own timed pieces
    (a dict of seconds).  One dict of seconds per run."""
    rows = []
    with patched(pieces, timed), tempfile.TemporaryDirectory() as tmp:
        for i in range(repeat):
            ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0, prediction_every=20)
            acc.clear()                 # the start's own calls of timed pieces count (the writer's first frame)
            logger, started = start(Path(tmp), i)
            acc.update(started)
            log_step = timed(log_label, logger.log_step)
            closed_loop(s, ctrl, x0, sim, model=model, lyap=clf.lyap,
                        on_step=lambda rec, st: log_step(rec, st, model))
            timed(close_label, logger.close)()
            rows.append(dict(acc))
    return rows


def print_pieces(title, column, rows, scale):
    """A markdown table of each piece's median over ``rows`` (dicts of seconds), times ``scale``."""
    print(f"\n{title}\n")
    print(f"| piece | {column} |")
    print("|---|---:|")
    for name in rows[0]:
        print(f"| {name} | {scale * np.median([r.get(name, 0.0) for r in rows]):.2f} |")


def process_breakdown(s, model, clf, h, x0, sim, repeat, timed, acc):
    """The same for the writer process (logging.writer=process): the parent's pieces, medians over ``repeat`` runs,
    per run (its start and close are once per run; packing and the pipe also happen inside log_step and close)."""
    from kexp.recording import process_log

    pieces = [(process_log, "pack_steps", "packing the records (one pickle, arrays as bytes)"),   # as process_log calls it
              (ProcessRunLogger, "_push", "writing to the pipe"),
              (lmpc_module, "rollout_poly", "the LMPC's exact rollouts for the plans")]

    def start(tmp, i):
        started_ahead()
        t = time.perf_counter()
        logger = ProcessRunLogger(tmp / f"p{i}.mcap", prediction_every=20, last_step=(sim.n_steps - 1) * sim.dt)
        return logger, {"start (opening the file, taking the child started ahead)": time.perf_counter() - t}

    rows = timed_runs(s, model, clf, h, x0, sim, repeat, timed, acc, pieces, start,
                      "log_step (all: keeping the record, and at each flush time the hand-over)",
                      "close (all: the child's answer waited for)")
    print_pieces(f"the writer process (logging.writer=process), {repeat} runs, medians per run [ms]",
                 "per run [ms]", rows, 1e3)


if __name__ == "__main__":
    main()
