"""A sweep worker runs job after job in one process: what a job opens it releases (the Rerun streams' native
threads above all; benchmarks/sweep_resources.py measures 200 jobs)."""
import json
import subprocess
import sys
from pathlib import Path

RECORDING = Path(__file__).resolve().parents[1] / "recordings" / "paper_vanderpol.mcap"

# Renders in a fresh interpreter (no other test's threads come and go meanwhile): one to load Rerun (its runtime
# threads stay for the process), then 5 more; the process's threads are counted from /proc/self/task, which sees
# the native ones (threading.active_count() does not).
_SCRIPT = """
import json, os, sys, tempfile
from pathlib import Path
from kexp.recording.render import render
from rerun.chunk import RrdReader

def threads():
    return len(os.listdir("/proc/self/task"))

def rss_mb():
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmRSS:")) / 1024

out = Path(tempfile.mkdtemp())
render(sys.argv[1], out / "warm.rrd")
before = (threads(), rss_mb())
for i in range(5):
    render(sys.argv[1], out / f"{i}.rrd")
import time
deadline = time.monotonic() + 30   # a thread being joined may take a moment on a loaded machine; leaked ones stay
while threads() - before[0] > 1 and time.monotonic() < deadline:
    time.sleep(0.1)
reader = RrdReader(out / "4.rrd")
print(json.dumps({"threads": [before[0], threads()], "rss": [before[1], rss_mb()],
                  "recordings": len(reader.recordings()), "blueprints": len(reader.blueprints())}))
"""


def test_renders_release_their_threads_and_memory(tmp_path):
    """Each render opened 4 native threads (ChunkBatcher and RecordingStream, for the data and for the blueprint
    stream) and never ended them: +20 threads after 5 renders.  The recording still holds its blueprint."""
    proc = subprocess.run([sys.executable, "-c", _SCRIPT, str(RECORDING)], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    before, after = res["threads"]
    assert after - before <= 1, res   # was +20; 1 for a runtime thread that may come and go
    rss_before, rss_after = res["rss"]
    assert rss_after - rss_before < 40, res   # MB; loose (allocator); measured +2 MB for 5 renders
    assert res["recordings"] == 1 and res["blueprints"] == 1
