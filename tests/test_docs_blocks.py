"""Every command block in the docs (docs/**/*.md and README.md) is either run by a test, as written, or listed here
as not run with the reason.  A fence must say its language: ``bash``, ``python`` and ``console`` (a command with its
output) are command blocks; ``text`` (output, messages) and ``yaml`` (config files) are not.  A new command block
fails here until it is given a test or a reason; a test named here must exist and read the page it is listed for."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = {"bash", "python", "console"}
LANGUAGES = COMMANDS | {"text", "yaml"}
SLOW = "a full experiment or sweep (minutes); "
# (page, a text found in exactly one of its command blocks, "tests/<file>.py::<test>" that runs it, or "not run: why")
BLOCKS = [
    ("README.md", "python3 -m venv .venv", "not run: makes a venv and installs into it; .ci/run does exactly this "
                                             "(tests/test_docs.py checks .ci/run against the README)"),
    ("README.md", "kexp                  # the default experiment",
     "not run: " + SLOW + "tests/test_app.py::test_default_job_end_to_end_small runs its config small"),
    ("docs/getting-started.md", "pip install -e '.[test]' && kexp", "not run: the README's two commands, see README.md"),
    ("docs/getting-started.md", "pip install .  ", "not run: installs into the running environment; "
                                                   "tests/test_packaging.py builds the wheel and installs it into a "
                                                   "fresh venv"),
    ("docs/getting-started.md", "kexp-compile", "not run: ~40 s of compiling; tests/test_jit_cache.py covers the cache"),
    ("docs/getting-started.md", "kexp --hydra-help", "not run: tests/test_cli_help.py runs each of these commands"),
    ("docs/guides/configs.md", "kexp +experiment=paper_pendulum", "not run: " + SLOW + "a list of overrides"),
    ("docs/guides/data-from-files.md", "data.source.path=myruns/", "not run: needs the user's folder myruns/"),
    ("docs/guides/data-from-files.md", "outputs/2026-11-23/18-00-00/run.mcap", "not run: needs an earlier run's log"),
    ("docs/guides/data-from-files.md", "python benchmarks/streaming.py", "not run: a benchmark (minutes)"),
    ("docs/guides/data-from-files.md", "kexp 'data.excitation={kind: prbs",
     "not run: " + SLOW + "tests/test_excitation.py covers excitation"),
    ("docs/guides/data-from-files.md", "import numpy as np, kexp",
     "tests/test_fit.py::test_the_readme_example_is_seven_lines_and_runs"),
    ("docs/guides/data-from-files.md", "model = kexp.fit(X, U, dt=0.01, degree=3)",
     "not run: an outline of the API on the user's arrays X, U and folder rig_runs/"),
    ("docs/guides/data-from-files.md", "python - <<'PY'", "tests/test_walkthrough.py::test_the_csv_walkthrough_runs_as_written"),
    ("docs/guides/data-from-files.md", "kexp system=data data.source.kind=files data.source.path=rig_runs",
     "not run: needs the walk-through's rig_runs/; tests/test_data_only.py runs system=data"),
    ("docs/guides/diff.md", "kexp-diff a.mcap b.mcap  ", "not run: needs two logs a.mcap, b.mcap"),
    ("docs/guides/diff.md", "python -m kexp.app.golden", "not run: rewrites the committed recordings/"),
    ("docs/guides/figures.md", "kexp-figures paper", "not run: needs run folders and sweeps (<date>/<time>)"),
    ("docs/guides/noise.md", "kexp data.noise.std=0.01", "not run: " + SLOW + "tests/test_noise.py covers the settings"),
    ("docs/guides/own-system.md", "# my_systems.py",
     "tests/test_own_system.py::test_readme_own_system_command_runs_as_written"),
    ("docs/guides/own-system.md", "PYTHONPATH=. kexp system.name=my_systems:Duffing2",
     "tests/test_own_system.py::test_readme_own_system_command_runs_as_written"),
    ("docs/guides/own-system.md", "PYTHONPATH=. kexp --config-dir myconf",
     "tests/test_own_system.py::test_the_readme_config_folder_of_ones_own_runs_as_written"),
    ("docs/guides/own-system.md", "kexp +experiment=duffing  ", "not run: " + SLOW + "three 100-run sweeps"),
    ("docs/guides/own-system.md", "PYTHONPATH=examples kexp +experiment=cartpole4",
     "not run: " + SLOW + "and a benchmark"),
    ("docs/guides/plants.md", "Path(\"my_rig.py\").write_text", "tests/test_plants_readme.py::test_the_plant_walkthrough_runs_as_written"),
    ("docs/guides/plants.md", "plant.env_id=Pendulum-v1 plant.equilibrium", "not run: an outline ('...' stands for "
                                                                              "the rest of the overrides)"),
    ("docs/guides/plants.md", "# your rig, no formula", "not run: needs the user's my_rig:Rig"),
    ("docs/guides/plants.md", "sim.realtime=true sim.open_loop=false", "not run: needs the user's my_rig:Rig, in real time"),
    ("docs/guides/plants.md", "X0=$(x0_box '-0.5,-0.2,0,0' '0.5,0.2,0,0' 7 300)",
     "not run: shell functions for sweeps; tests/test_robustness_table.py runs results/sweep_lib.sh"),
    ("docs/guides/plants.md", "sweep_row cartpole_lmpc", "not run: " + SLOW + "three 100-run sweeps"),
    ("docs/guides/plants.md", "kexp +experiment=gym_pendulum  ",
     "not run: " + SLOW + "tests/test_plants_results.py::test_the_presets_run_as_the_readme_says runs both presets"),
    ("docs/guides/plants.md", "# my_maps.py", "not run: a sketch for a plant whose state is not its observation "
                                              "(CartPole); tests/test_plant_gymnasium.py covers plant.state"),
    ("docs/method.md", "kexp +experiment=vanderpol 'data.excitation={low: -1.0, high: 1.0, hold: 10}'",
     "not run: " + SLOW + "tests/test_excitation.py covers excitation"),
    ("docs/guides/pytest-plugin.md", "# tests/test_my_controller.py",
     "tests/test_testing_plugin.py::test_the_readme_worked_example_runs_as_written"),
    ("docs/guides/pytest-plugin.md", "pytest --kexp-regen", "not run: pytest in the user's project; "
                                                           "tests/test_testing_plugin.py runs the plugin through pytester"),
    ("docs/guides/python-api.md", "from kexp.systems import make_system",
     "tests/test_readme_api.py::test_the_python_api_section_runs_as_written"),
    ("docs/guides/python-api.md", "from kexp.recording import RunLogger, diff_logs, read_log",
     "tests/test_readme_api.py::test_the_python_api_section_runs_as_written"),
    ("docs/guides/rerun.md", "kexp-render outputs/", "not run: needs a run folder, and a display or a browser"),
    ("docs/guides/rerun.md", "rerun --web-viewer run.rrd", "not run: starts a viewer server that runs until stopped"),
    ("docs/guides/sweeps.md", "clf.gamma=1,2", "not run: " + SLOW + "examples of multirun overrides"),
    ("docs/guides/sweeps.md", "sweep.resume=true", "not run: " + SLOW + "tests/test_sweep_jobs.py covers resume"),
    ("docs/method.md", "kexp identification.estimator=iv  ", "not run: " + SLOW + "tests/test_iv.py runs IV"),
    ("docs/method.md", "kexp system=linear 'system.params.A=",
     "tests/test_clf_bound.py::test_the_docs_command_of_the_blind_v_prints_what_the_docs_say"),
    ("docs/results.md", "kexp-results table results/*.csv > results/table.md", "not run: " + SLOW + "the results' sweeps"),
    ("docs/results.md", "results/reproduce.sh --sample 10", "not run: re-runs committed rows (minutes); "
                                                             "tests/test_reproduce.py runs the script with kexp stubbed"),
    ("docs/results.md", "results/robustness.sh --list", "not run: " + SLOW + "tests/test_robustness_table.py runs the "
                                                         "script with kexp stubbed"),
    ("docs/benchmarks.md", "python benchmarks/sweep_resources.py", "not run: a benchmark (minutes)"),
]


def pages() -> list[Path]:
    return [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))


def fences(path: Path) -> list[tuple[str, str]]:
    """(language, body) of each fenced block; a fence without a language gives ''."""
    out, lang, body = [], None, []
    for line in path.read_text(encoding="utf-8").split("\n"):
        if line.lstrip().startswith("```"):
            if lang is None:
                lang, body = line.lstrip()[3:].strip(), []
            else:
                out.append((lang, "\n".join(body)))
                lang = None
        elif lang is not None:
            body.append(line)
    assert lang is None, f"{path}: a fence is not closed"
    return out


def test_every_fence_says_its_language():
    bad = [(p.relative_to(ROOT).as_posix(), body.split("\n")[0][:60]) for p in pages() for lang, body in fences(p)
           if lang not in LANGUAGES]
    assert not bad, f"fences without one of {sorted(LANGUAGES)}: {bad}"


def test_every_command_block_is_run_by_a_test_or_says_why_not():
    blocks = [(p.relative_to(ROOT).as_posix(), body) for p in pages() for lang, body in fences(p) if lang in COMMANDS]
    assert len(blocks) >= 40
    listed = {(page, key): [b for pg, b in blocks if pg == page and key in b] for page, key, _ in BLOCKS}
    ambiguous = {k: len(v) for k, v in listed.items() if len(v) != 1}
    assert not ambiguous, f"entries matching no block or several (page, text: count): {ambiguous}"
    unlisted = [(page, body.split("\n")[0][:80]) for page, body in blocks
                if not any(page == pg and key in body for pg, key, _ in BLOCKS)]
    assert not unlisted, f"command blocks no test runs and no reason lists (add them to BLOCKS): {unlisted}"


def test_each_named_test_exists_and_reads_its_page():
    for page, key, how in BLOCKS:
        if how.startswith("not run: "):
            assert len(how.split()) >= 5, (page, key, "say why it is not run")
            continue
        file, name = how.split("::")
        source = (ROOT / file).read_text(encoding="utf-8")
        assert re.search(rf"^def {name}\(", source, re.M), f"{how}: no such test"
        parts = Path(page).parts
        assert all(f'"{part}"' in source for part in parts), f"{file} does not read {page}"
