"""How far the golden recordings move under real variation of the linear-algebra path, against the portable
diff policy's tolerances (kexp/recording/policy.py).

Each golden config is re-run in a fresh process for every OpenBLAS kernel this CPU can execute
(OPENBLAS_CORETYPE) × BLAS thread count (1, 2), and diffed against the committed recording.  For each channel the
table gives the largest |Δ| / tolerance under the portable policy (1 = at the bound; "0" = identical), and
whether the exact policy would have passed.

    python benchmarks/golden_variation.py [--names paper_pendulum paper_vanderpol] [--threads 1 2]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from kexp.app import golden
from kexp.recording import diff_logs

RECORD = """
import json, sys
from pathlib import Path
from threadpoolctl import threadpool_info
from kexp.app.golden import record
record(sys.argv[1], Path(sys.argv[2]))
blas = [i for i in threadpool_info() if i["user_api"] == "blas" and "numpy" in i["filepath"]]
print(json.dumps({"arch": blas[0].get("architecture") if blas else None}))
"""
KERNELS = {"Prescott": "pni", "Nehalem": "sse4_2", "Sandybridge": "avx", "Haswell": "avx2", "Zen": "avx2",
           "SkylakeX": "avx512f", "Cooperlake": "avx512_bf16"}
CHANNELS = ("/model", "/clf", "/step", "/prediction", "/open_loop", "/summary")


def cpu_flags() -> set:
    try:
        return {f for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags")
                for f in line.split(":", 1)[1].split()}
    except OSError:
        return set()


def record(name, out, threads, coretype):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OPENBLAS_", "OMP_", "MKL_"))}
    env["OPENBLAS_NUM_THREADS"] = str(threads)
    if coretype:
        env["OPENBLAS_CORETYPE"] = coretype
    proc = subprocess.run([sys.executable, "-c", RECORD, name, str(out)], env=env, capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(proc.stderr[-2000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])["arch"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--names", nargs="*", default=sorted(golden.GOLDEN))
    p.add_argument("--threads", nargs="*", type=int, default=[1, 2])
    args = p.parse_args(argv)
    flags = cpu_flags()
    kernels = [None] + [k for k, f in KERNELS.items() if f in flags]
    print("| golden | kernel (reported) | threads | exact | " + " | ".join(CHANNELS) + " |")
    print("|---|---|---|---|" + "---|" * len(CHANNELS))
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.names:
            for kernel in kernels:
                for threads in args.threads:
                    out = Path(tmp) / f"{name}_{kernel}_{threads}.mcap"
                    arch = record(name, out, threads, kernel)
                    committed = golden.RECORDINGS / f"{name}.mcap"
                    exact = diff_logs(committed, out).equal
                    res = diff_logs(committed, out, policy="portable")
                    cells = [f"{res.usage.get(c, 0.0):.2g}" for c in CHANNELS]
                    verdict = "" if res.equal else " **FAILS**"
                    print(f"| {name} | {kernel or 'default'} ({arch}) | {threads} | {'equal' if exact else 'differs'} "
                          f"| " + " | ".join(cells) + f" |{verdict}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
