"""The extras keep a driver-only install light: the run path on a rig imports neither dm_control nor
torch, and a command that needs a missing extra says which one in one line. A module "not installed"
is made so the way Python itself allows (None in sys.modules: its import raises ModuleNotFoundError)."""

import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

WITHOUT = (
    "import sys\n"
    "for name in ('dm_control', 'torch', 'gmsh', 'meshio', 'gymnasium'):\n"
    "    sys.modules[name] = None\n"
)


def _python(code: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", WITHOUT + code], capture_output=True, text=True, cwd=cwd)


def test_torch_and_the_sim_stack_are_extras_not_the_base():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    base = " ".join(project["dependencies"])
    assert "torch" not in base and "dm-control" not in base and "gmsh" not in base
    extras = project["optional-dependencies"]
    assert extras["shape"] == ["torch==2.13.0"]
    assert any(r.startswith("dm-control==") for r in extras["sim"])
    (own,) = [r for r in extras["test"] if r.startswith("barrett-twin[")]  # the suite installs them all
    assert {"sim", "shape", "gym", "rl"} <= set(own.removeprefix("barrett-twin[").rstrip("]").split(","))
    assert not any(r.startswith("torch") for r in extras["rl"])  # torch only through [shape]'s pin


def test_a_rig_run_imports_no_sim_and_no_torch(tmp_path: Path):
    code = (
        "import twin\n"
        "from twin.session import run_experiment\n"
        "from twin.experiments.compress import CompressController\n"
        "import twin.hardware.bh262.hand, twin.viz.rerun_log\n"
        "backend = twin.hardware_backend(hand='socket://127.0.0.1:9')\n"
        "print(type(backend).__name__, sorted(m for m in ('dm_control', 'torch') if sys.modules.get(m)))\n"
    )
    result = _python(code, tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["HardwareBackend", "[]"]


def test_a_command_that_needs_a_missing_extra_says_which_in_one_line(tmp_path: Path):
    code = "from twin.cli import main\nsys.exit(main(['run', 'compress', '--out', 'r', '--no-progress']))\n"
    result = _python(code, tmp_path)
    assert result.returncode == 2
    err = result.stderr
    assert err.count("\n") == 1 and "pip install 'barrett-twin[sim]'" in err, err
    assert not (tmp_path / "r").exists()
