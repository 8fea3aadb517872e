"""A user's own system and presets outside the repository (issue 11, item 5): the docs' example (docs/guides/own-system.md) as written, a config
folder of one's own on Hydra's search path, and a changed system.name starting from clean parameters."""
import os
import re
import shlex
import subprocess
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from kexp.app.conf import CONF_DIR
from kexp.app.experiment import config_dict
from kexp.recording import read_log

from cli import console_script

PAGE = Path(__file__).resolve().parents[1] / "docs" / "guides" / "own-system.md"
# small enough to take seconds (as in tests/test_recording.py)
SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=1.0", "clf.grid=11", "logging.rrd=false", "logging.progress=false",
         "cache.enabled=false"]


def _readme_section() -> str:
    text = PAGE.read_text()
    return text[:text.index("\n## Four states and more")]


def _readme_module() -> str:
    """The docs' my_systems.py, as written."""
    blocks = re.findall(r"```python\n(.*?)```", _readme_section(), re.S)
    return next(b for b in blocks if b.startswith("# my_systems.py"))


def _env(extra: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(extra), str(Path(__file__).resolve().parents[1])] +
                                        [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    return env


def _kexp(args, cwd: Path, timeout=300):
    return subprocess.run([console_script("kexp"), *args], cwd=cwd, env=_env(cwd), capture_output=True, text=True,
                          timeout=timeout)


def _logged_system(run_dir: Path) -> dict:
    return read_log(run_dir / "run.mcap").one("/config")["config"]["system"]


def _one_line_error(proc) -> str:
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("kexp: error: "), proc.stderr
    return lines[0]


def test_readme_own_system_command_runs_as_written(tmp_path):
    (tmp_path / "my_systems.py").write_text(_readme_module())
    line = next(ln for ln in _readme_section().splitlines() if ln.startswith("PYTHONPATH=. kexp "))
    argv = shlex.split(line)[2:]  # after `PYTHONPATH=. kexp`: PYTHONPATH is set in _env
    proc = _kexp(argv + SMALL + [f"hydra.run.dir={tmp_path / 'run'}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    # the class gets alpha=2.0 and none of the default preset's (vanderpol's) parameters
    assert _logged_system(tmp_path / "run") == {"name": "my_systems:Duffing2", "params": {"alpha": 2.0}}
    assert "Koopman bilinear model of duffing2" in proc.stdout


DUFFING2 = """\
from dataclasses import dataclass
from typing import ClassVar
import numpy as np
from kexp.systems import ControlAffineSystem

@dataclass(frozen=True)
class Duffing2(ControlAffineSystem):
    alpha: float = 1.0
    beta: float = 1.0
    name: ClassVar[str] = "duffing2"
    n: ClassVar[int] = 2
    m: ClassVar[int] = 1
    def drift(self, x):
        x = np.asarray(x)
        return np.stack([x[..., 1], self.alpha * x[..., 0] - self.beta * x[..., 0] ** 3 - 0.5 * x[..., 1]], axis=-1)
    def input_matrix(self, x):
        return np.broadcast_to([[0.0], [1.0]], np.shape(x)[:-1] + (2, 1)).copy()
"""


def _user_folder(tmp_path: Path) -> Path:
    """my_systems.py and a config folder of the user's own: system/duffing2.yaml and experiment/mine.yaml."""
    (tmp_path / "my_systems.py").write_text(DUFFING2)
    conf = tmp_path / "myconf"
    (conf / "system").mkdir(parents=True)
    (conf / "experiment").mkdir()
    (conf / "system" / "duffing2.yaml").write_text("name: my_systems:Duffing2\nparams:\n  alpha: 2.0\n")
    (conf / "experiment" / "mine.yaml").write_text(
        "# @package _global_\ndefaults:\n  - override /system: duffing2\n  - override /data: box\n\n"
        "clf:\n  method: lqr_x\n  rhat_floor: 1.0\ncontroller:\n  law: sontag\n")
    (conf / "experiment" / "broken.yaml").write_text("# @package _global_\ncontroller: [unclosed\n  law: : :\n")
    return conf


def test_the_readme_config_folder_of_ones_own_runs_as_written(tmp_path):
    """The docs' myconf/system/duffing2.yaml and myconf/experiment/mine.yaml, and its --config-dir command."""
    (tmp_path / "my_systems.py").write_text(_readme_module())
    for block in re.findall(r"```yaml\n(.*?)```", _readme_section(), re.S):
        path = tmp_path / re.search(r"^# (myconf/\S+\.yaml)", block, re.M).group(1)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(block)
    assert (tmp_path / "myconf" / "system" / "duffing2.yaml").exists()
    line = next(ln for ln in _readme_section().splitlines() if ln.startswith("PYTHONPATH=. kexp --config-dir"))
    argv = shlex.split(line.split("#")[0])[2:]
    proc = _kexp(argv + SMALL + [f"hydra.run.dir={tmp_path / 'run'}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert _logged_system(tmp_path / "run") == {"name": "my_systems:Duffing2", "params": {"alpha": 2.0}}
    config = read_log(tmp_path / "run" / "run.mcap").one("/config")["config"]
    assert config["data"]["sampler"]["kind"] == "box" and config["clf"]["method"] == "lqr_x"  # the preset applied


@pytest.mark.parametrize("args,fragment", [
    (["--config-dir", "myconf", "+experiment=nope"], "Could not find 'experiment/nope'"),
    (["--config-dir=myconf", "+experiment=mine", "controller.lmpc.horizon=abc"],
     "controller.lmpc.horizon: Value 'abc' of type 'str' could not be converted to Integer"),
    (["-cd", "myconf", "+experiment=broken"], "experiment/broken.yaml: not valid YAML: expected ',' or ']'"),
    (["+experiment=broken", "hydra.searchpath=[file://myconf]"], "not valid YAML"),
    (["-cd", "myconf", "+experiment=mine", "system.params.alpha=abc"], "drift(x) raised UFuncTypeError"),
    # sweeps: a file that is not YAML, a swept value of the wrong type, with a config dir of one's own
    (["-m", "-cd", "myconf", "+experiment=broken", "sim.T=1.0,2.0"], "experiment/broken.yaml: not valid YAML"),
    (["-m", "--config-dir", "myconf", "+experiment=mine", "sim.T=1.0,abc"],
     "sim.T: Value 'abc' of type 'str' could not be converted to Float"),
])
def test_errors_with_an_outside_config_dir_are_one_line_exit_2(tmp_path, args, fragment):
    _user_folder(tmp_path)
    line = _one_line_error(_kexp(args + [f"hydra.run.dir={tmp_path / 'run'}"], tmp_path, timeout=120))
    assert fragment in line


def _system(overrides, conf_dir=None):
    extra = [f"hydra.searchpath=[file://{conf_dir}]"] if conf_dir else []
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return config_dict(compose(config_name="config", overrides=extra + overrides))["system"]


@pytest.mark.parametrize("overrides,params", [
    # a changed name: the group file's parameters are dropped, the ones given after it stay
    (["system.name=my_systems:Duffing2", "+system.params={alpha: 2.0}"], {"alpha": 2.0}),
    (["+experiment=duffing", "system.name=my_systems:Duffing2"], {}),
    (["+experiment=duffing", "system.name=my_systems:Duffing2", "system.params.beta=3.0"], {"beta": 3.0}),
    (["system.name=my_systems:Duffing2", "system.params=null"], {}),
    # the same system: its file's parameters with the overrides
    (["system=duffing", "system.params.alpha=3.0"], {"alpha": 3.0, "beta": 1.0, "delta": 0.5}),
    (["system=vanderpol"], {"mu": 1.0}),
])
def test_a_changed_system_name_starts_from_clean_parameters(overrides, params):
    assert _system(overrides)["params"] == params


def test_a_copied_preset_switched_to_a_user_class_keeps_only_its_own_parameters(tmp_path):
    conf = tmp_path / "conf" / "experiment"
    conf.mkdir(parents=True)
    duffing = (Path(CONF_DIR) / "experiment" / "duffing.yaml").read_text()
    (conf / "mine.yaml").write_text(duffing + "system:\n  name: my_systems:Duffing2\n  params:\n    alpha: 2.0\n")
    assert _system(["+experiment=mine"], tmp_path / "conf") == {"name": "my_systems:Duffing2",
                                                                "params": {"alpha": 2.0}}
