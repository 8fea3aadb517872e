"""Can the tests fail?  A mutation audit: each one-line change of tests/data/mutations.json is applied to a clone of
the repository's HEAD, and the tests it names are run against it (with that clone first on PYTHONPATH).  A
mutation is *caught* when those tests fail.  Every mutation is expected to be caught unless its entry says why it
survives ("survives": an equivalent change, or one no test can see); the audit exits 1 when a mutation expected to
be caught survives (a test that cannot fail, or code no test checks) or one expected to survive is caught (update
its entry).  Not part of the suite (minutes, not seconds): run it at a stop that touches the tests or the core.

    python tests/mutation_audit.py [ID ...]        # all mutations, or those named; ~20 min on 2 cores

tests/test_mutation_list.py keeps the list valid as the code changes (each change applies to exactly one place).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MUTATIONS = ROOT / "tests" / "data" / "mutations.json"


def load(path: Path = MUTATIONS) -> list[dict]:
    """The mutations: id, file, old (the text replaced, found exactly once), new, tests, survives (why it is
    expected to survive, or '')."""
    return json.loads(path.read_text())


def names_a_test(node: str) -> bool:
    """A test file of the repository, or ``file::test_name`` of a test defined in it: a test that does not exist
    would make pytest fail, and the mutation would count as caught."""
    path, _, name = node.partition("::")
    f = ROOT / path
    if not (f.is_file() and Path(path).name.startswith("test_")):
        return False
    return not name or (name.startswith("test_") and "::" not in name and f"def {name}(" in f.read_text())


def run_one(clone: Path, m: dict) -> tuple[bool, str]:
    """Apply ``m`` in ``clone``, run its tests there, restore the file: (caught, pytest's last line)."""
    f = clone / m["file"]
    src = f.read_text()
    if src.count(m["old"]) != 1:
        raise SystemExit(f"{m['id']}: its text is found {src.count(m['old'])} times in {m['file']}; fix "
                         f"{MUTATIONS.relative_to(ROOT)}")
    f.write_text(src.replace(m["old"], m["new"]))
    try:
        proc = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *m["tests"]],
                              cwd=clone, env={**os.environ, "PYTHONPATH": str(clone)}, capture_output=True,
                              text=True)
    finally:
        f.write_text(src)
    lines = proc.stdout.strip().splitlines()
    return proc.returncode != 0, lines[-1] if lines else proc.stderr.strip()[-200:]


def main(argv: list[str] | None = None) -> int:
    ids = list(sys.argv[1:] if argv is None else argv)
    muts = load()
    unknown = set(ids) - {m["id"] for m in muts}
    if unknown:
        print(f"unknown mutation(s): {', '.join(sorted(unknown))}", file=sys.stderr)
        return 2
    muts = [m for m in muts if not ids or m["id"] in ids]
    missing = [f"{m['id']}: {t}" for m in muts for t in m["tests"] if not names_a_test(t)]
    if missing:
        print(f"no such test (fix {MUTATIONS.relative_to(ROOT)}): {'; '.join(missing)}", file=sys.stderr)
        return 2
    wrong = []
    with tempfile.TemporaryDirectory() as tmp:
        clone = Path(tmp) / "repo"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        print(f"{len(muts)} mutations of HEAD, each file's tests run in {clone}\n")
        print("| mutation | file | expected | result |\n|---|---|---|---|")
        for m in muts:
            t0 = time.perf_counter()
            caught, last = run_one(clone, m)
            expected = "survives" if m["survives"] else "caught"
            got = "caught" if caught else "survives"
            if got != expected:
                wrong.append(m["id"])
            note = f" ({m['survives']})" if m["survives"] else ""
            flag = "" if got == expected else " ← UNEXPECTED"
            print(f"| {m['id']} | {m['file']} | {expected}{note} | {got}, {time.perf_counter() - t0:.0f} s: "
                  f"{last}{flag} |", flush=True)
    caught = len(muts) - sum(bool(m["survives"]) for m in muts)
    print(f"{caught} expected caught, {len(muts) - caught} expected to survive; "
          + (f"unexpected: {', '.join(wrong)}" if wrong else "every result as expected"))
    return 1 if wrong else 0


if __name__ == "__main__":
    sys.exit(main())
