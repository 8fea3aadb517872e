"""The mutation audit's list (tests/data/mutations.json, run by tests/mutation_audit.py) stays valid as the code
changes: each mutation applies to exactly one place, changes it, names test files (or tests in them, file::name) that
exist, and says why when it is expected to survive."""
from pathlib import Path

from mutation_audit import ROOT, load, names_a_test


def test_each_mutation_applies_to_exactly_one_place():
    muts = load()
    assert len(muts) >= 218 and len({m["id"] for m in muts}) == len(muts)
    for m in muts:
        src = (ROOT / m["file"]).read_text()
        assert src.count(m["old"]) == 1, f"{m['id']}: {m['old']!r} is found {src.count(m['old'])} times in {m['file']}"
        assert m["new"] != m["old"] and m["tests"], m["id"]
        assert all(names_a_test(t) for t in m["tests"]), m["id"]
        assert isinstance(m["survives"], str), m["id"]
    # the few expected to survive each say why; the rest are expected to be caught
    survivors = {m["id"] for m in muts if m["survives"]}
    assert survivors == {"lmpc_argmin", "zoh_tail", "cert_bad", "flush_due", "steps_default", "parsed_line_limit"}


def test_a_mutation_s_tests_must_exist():
    assert names_a_test("tests/test_oracle.py")
    assert names_a_test("tests/test_oracle.py::test_symbolic_models_of_shipped_systems")
    assert not names_a_test("tests/test_oracle.py::test_no_such_test")
    assert not names_a_test("tests/no_such_file.py")
    assert not names_a_test("tests/mutation_audit.py")
