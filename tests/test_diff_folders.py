"""kexp-diff takes run folders (as the pytest plugin and kexp-figures do) as well as .mcap files."""
import subprocess

from kexp.recording.diff import main as diff_main
from kexp.recording.reader import log_path
from kexp.recording.writer import RunLogger

from test_cli_help import script


def _run_folder(folder, u=0.1, steps=5):
    """A run folder holding a small run.mcap: /config, ``steps`` /step messages with input ``u``, /summary."""
    folder.mkdir(parents=True)
    with RunLogger(folder / "run.mcap") as log:
        log.log_config({"system": {"name": "vanderpol"}}, "0")
        for k in range(steps):
            log.write("/step", 0.01 * k, {"k": k, "t": 0.01 * k, "x": [0.5, -0.3], "u": [u]})
        log.log_summary(0.01 * steps, "completed", "", {"cost": 1.0}, True)
    return folder


def test_run_folders_and_mcap_files_are_diffed_alike(tmp_path, capsys):
    a, b = _run_folder(tmp_path / "a"), _run_folder(tmp_path / "b")
    c = _run_folder(tmp_path / "c", u=0.2)
    assert log_path(a) == a / "run.mcap" and log_path(a / "run.mcap") == a / "run.mcap"
    assert diff_main([str(a), str(b)]) == 0
    folders = capsys.readouterr().out
    assert folders.startswith("logs are equal (exact)\n") and "/step" in folders
    assert diff_main([str(a / "run.mcap"), str(b / "run.mcap")]) == 0 and capsys.readouterr().out == folders
    assert diff_main([str(a), str(b / "run.mcap")]) == 0 and capsys.readouterr().out == folders
    assert diff_main([str(a), str(c)]) == 1
    assert capsys.readouterr().out.startswith("first divergence: channel /step, step 0 (t = 0 s), field u[0]: "
                                              "0.1 != 0.2")


def test_a_folder_without_a_log_is_one_line_and_exit_2(tmp_path):
    a = _run_folder(tmp_path / "a")
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "summary.json").write_text("{}")
    proc = subprocess.run([*script("kexp-diff"), str(a), str(empty)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr == (f"kexp-diff: error: no run log at {empty / 'run.mcap'} (pass a run folder holding "
                           "run.mcap, or an .mcap file; a run with logging.mcap=false writes none)\n")
