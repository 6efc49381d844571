"""A wheel built from the repository, installed into a fresh virtual environment (no editable link to
the checkout), runs a short compress from a directory outside the checkout: the hand's MJCF ships as
package data (issue 23: `pip install .` once left models/barrett_mjcf out and `twin run` died).

The new environment reuses this one's installed dependencies through a path entry, so nothing is
downloaded; the project itself comes only from the wheel (checked: `twin.__file__`)."""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGED = {"twin", "hardware", "experiments", "models", "pyproject.toml", "README.md", "LICENSE"}
"""What a wheel is built from: the packages, the hand's model and the project's files."""


def _source_copy(dest: Path) -> Path:
    """The checkout's files as git sees them (tracked and new, not ignored): no stale build/ output."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT, capture_output=True, check=True,
    ).stdout.decode().split("\0")  # fmt: skip
    for rel in filter(None, listed):
        if (ROOT / rel).is_file() and (rel.split("/")[0] in PACKAGED or rel in PACKAGED):
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(ROOT / rel, dest / rel)
    return dest


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git to list the checkout's files")
def test_a_wheel_installed_in_a_fresh_venv_runs_compress_outside_the_checkout(tmp_path: Path):
    src = _source_copy(tmp_path / "src")
    wheels = tmp_path / "wheels"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    subprocess.run(
        [*pip, "wheel", "--no-deps", "--no-build-isolation", "-q", str(src), "-w", str(wheels)],
        check=True, capture_output=True,
    )  # fmt: skip
    (wheel,) = wheels.glob("barrett_twin-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "models/barrett_mjcf/scene.xml" in names and "models/barrett_mjcf/bh8.xml" in names

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True, text=True, check=True,
    ).stdout.strip()  # fmt: skip
    # this environment's dependencies, as a plain path: its .pth files (the editable link) are not read
    Path(site, "deps_from_test_env.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run(
        [*pip, "--python", str(python), "install", "-q", "--no-deps", "--no-index", str(wheel)],
        check=True, capture_output=True,
    )  # fmt: skip

    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    twin = str(venv / "bin" / "twin")
    version = subprocess.run([twin, "--version"], capture_output=True, text=True, cwd=work, env=env)
    assert version.returncode == 0 and version.stdout.strip() == "twin 0.1.0", version
    result = subprocess.run(
        [twin, "run", "compress", "--duration", "2", "--out", "r", "--no-progress"],
        capture_output=True, text=True, cwd=work, env=env, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    info = json.loads((work / "r" / "run.json").read_text())
    assert info["status"] == "complete"
    where = subprocess.run(
        [str(python), "-c", "import twin.sim.scene as s, twin; print(twin.__file__); print(s.MODEL_DIR)"],
        capture_output=True, text=True, cwd=work, env=env, check=True,
    ).stdout.split()  # fmt: skip
    assert all(Path(p).is_relative_to(venv) for p in where), where  # the wheel's files, not the checkout's
