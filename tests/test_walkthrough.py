"""The docs' walk-through (docs/guides/data-from-files.md) "Your system, known only through a folder of CSV runs", run as written: its Python
block writes the rig's CSV runs, its first command identifies from them with B and b regressed (G unused) and
stabilises the closed loop, with a log and a Rerun recording."""
import json
import re
import subprocess
import sys
from pathlib import Path
from cli import console_script

PAGE = Path(__file__).resolve().parents[1] / "docs" / "guides" / "data-from-files.md"


def _section() -> str:
    text = PAGE.read_text()
    start = text.index("\n## Your system, known only through a folder of CSV runs")
    return text[start:text.index("\n## ", start + 10)]


def test_the_csv_walkthrough_runs_as_written(tmp_path):
    sec = _section()
    script = re.search(r"python - <<'PY'\n(.*?)\nPY\n", sec, flags=re.S).group(1)
    proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    runs = sorted((tmp_path / "rig_runs").glob("*.csv"))
    assert len(runs) == 60 and runs[0].read_text().splitlines()[0] == "t,x1,x2,u1"

    command = next(line for line in sec.splitlines() if line.startswith("kexp +experiment=vanderpol data.source"))
    args = command.split()[1:] + ["logging.progress=false", f"cache.dir={tmp_path / 'cache'}",
                                  f"hydra.run.dir={tmp_path / 'run'}"]
    proc = subprocess.run([console_script("kexp"), *args], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "G not used" in proc.stdout and "result: settled (completed)" in proc.stdout
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["metrics"]["success"]
    assert {p.name for p in (tmp_path / "run").iterdir()} >= {"run.mcap", "run.rrd", "model.npz"}
