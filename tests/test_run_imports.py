"""A run imports what it uses: a sim run without cameras loads neither the vision stack (OpenCV,
scipy.ndimage, scikit-image behind twin.vision) nor OpenGL. Each run is in a fresh interpreter, as a
user starts it, with MUJOCO_GL unset (the suite's conftest sets it for its own process)."""

import json
import os
import subprocess
import sys
from pathlib import Path

VISION_OR_GL = ("twin.vision", "OpenGL", "cv2", "scipy.ndimage", "skimage")


def _modules_after(script: str, cwd: Path) -> list[str]:
    """Run `script` in a fresh interpreter; the modules it had imported when it ended."""
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY")}
    code = f"{script}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.splitlines()[-1])


def _loaded(modules: list[str], prefixes: tuple[str, ...]) -> list[str]:
    return [m for m in modules if any(m == p or m.startswith(p + ".") for p in prefixes)]


def test_cli_run_without_cameras_imports_no_vision_and_no_opengl(tmp_path: Path):
    script = (
        "from twin.cli import main\n"
        "status = main(['run', 'compress', '--object', 'block', '--duration', '0.3', '--out', 'run', "
        "'--no-progress'])\n"
        "assert status == 0, status"
    )
    modules = _modules_after(script, tmp_path)
    assert "twin.sim.backend" in modules and "rerun" in modules  # the run did run, and logged
    assert (tmp_path / "run" / "run.rrd").is_file()
    assert _loaded(modules, VISION_OR_GL) == []


def test_api_run_without_cameras_imports_no_vision(tmp_path: Path):
    script = "import twin\ntwin.compress(twin.sim_backend('block'), duration_s=0.3, out='run')"
    modules = _modules_after(script, tmp_path)
    assert "twin.sim.backend" in modules
    # OpenGL is MuJoCo's own at its import here: the library keeps MUJOCO_GL=egl as the default for a
    # caller's own mujoco.Renderer (twin/__init__.py); the CLI turns that default context off.
    assert _loaded(modules, ("twin.vision", "cv2", "scipy.ndimage", "skimage")) == []


def test_the_twins_own_simulations_write_no_recording_and_import_no_rerun(tmp_path: Path):
    """twin.sim.modulus's simulations read the run's streams alone: `viewer=False` writes every stream
    and no run.rrd, and never imports Rerun (a second per worker, and 15-20 % of each simulation)."""
    script = (
        "from twin.experiments.compress import run_compress\n"
        "from twin.sim.backend import SimBackend\n"
        "from twin.sim.foam import get_object\n"
        "from twin.recording import open_run\n"
        "run_compress(SimBackend(get_object('block'), seed=1), 'run', duration_s=0.5, object_name='block',"
        " viewer=False)\n"
        "run = open_run('run')\n"
        "hand = run.stream('hand')\n"
        "assert run.status == 'complete' and len(hand) == 16, (run.status, len(hand))"
    )
    modules = _modules_after(script, tmp_path)
    assert "twin.rig" in modules and _loaded(modules, ("rerun", "twin.viz")) == []
    assert not (tmp_path / "run" / "run.rrd").exists()
    assert (tmp_path / "run" / "run.json").is_file()


def test_a_hardware_run_without_cameras_imports_no_opencv(tmp_path: Path):
    """The emulated rig without cameras, its rig file read and a short hardware run through the bridge:
    OpenCV is the cameras' (their capture and their JPEG frames), so neither side loads it."""
    script = (
        "from twin.cli import main\n"
        "from twin.hardware.rig_emulator import RigEmulator\n"
        "with RigEmulator('block', seed=0) as emulator:\n"
        "    emulator.serve('pty')\n"
        "    rig = emulator.write_rig_file('rig/rig.toml')\n"
        "    status = main(['run', 'compress', '--backend', 'hardware', '--rig', str(rig), "
        "'--duration', '0.5', '--out', 'run', '--no-progress'])\n"
        "assert status == 0, status"
    )
    modules = _modules_after(script, tmp_path)
    assert "twin.hardware.backend" in modules and "twin.hardware.pps.driver" in modules  # it ran the rig
    assert json.loads((tmp_path / "run" / "run.json").read_text())["status"] == "complete"
    # OpenGL is MuJoCo's own here, as in the API run above: the emulator's twin is imported as a library.
    assert _loaded(modules, ("twin.vision", "cv2", "scipy.ndimage", "skimage")) == []
