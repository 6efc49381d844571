"""A wheel built from the repository, installed into a fresh virtual environment (no editable link to
the checkout), puts one top-level package, `twin`, in site-packages (issue 40: it once installed
`hardware`, `experiments` and `models` beside it) and runs a short compress from a user's directory that
holds folders of those names; the hand's MJCF ships as package data (issue 23: `pip install .` once left
models/barrett_mjcf out and `twin run` died).

The new environment reuses this one's installed dependencies through a path entry, so nothing is
downloaded; the project itself comes only from the wheel (checked: every `twin` module's file)."""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import textwrap
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGED = {"twin", "hardware", "experiments", "models", "pyproject.toml", "README.md", "LICENSE"}
"""What a wheel is built from: the packages, the hand's model and the project's files."""
DIST_INFO = "barrett_twin-0.1.0.dist-info"
DEPS_PTH = "deps_from_test_env.pth"
USER_FOLDERS = ("hardware", "experiments", "models")
"""The commonest folder names in a research repository, and the repository's own top-level folders."""

USER_SCRIPT = textwrap.dedent(
    """
    import json, sys
    from pathlib import Path

    import mujoco

    import twin
    import twin.experiments.compress
    import twin.hardware.backend
    from twin.assets import HAND_XML, MODEL_DIR, SCENE_XML

    mujoco.MjModel.from_xml_path(str(HAND_XML))
    mujoco.MjModel.from_xml_path(str(SCENE_XML))
    rig = twin.hardware_backend(hand="socket://127.0.0.1:9")  # built, not connected
    run = twin.compress(twin.sim_backend("block"), duration_s=0.5, out="r")
    loaded = [m for n, m in sys.modules.items() if n.split(".")[0] == "twin"]
    files = sorted({m.__file__ for m in loaded if getattr(m, "__file__", None)})
    theirs = sorted(n for n in sys.modules if n.split(".")[0] in ("hardware", "experiments", "models"))
    try:
        import experiments  # this directory's own folder, untouched by the install
    except RuntimeError as exc:
        mine = str(exc)
    print(json.dumps({"status": run.status, "backend": type(rig).__name__, "model_dir": str(MODEL_DIR),
                      "files": files, "theirs": theirs, "mine": mine}))
    """
)


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


def _user_directory(work: Path) -> Path:
    """A user's project: folders named like the repository's, each a package that fails on import, a
    bogus bh8.xml where a path relative to the working directory would look, and their script."""
    for name in USER_FOLDERS:
        (work / name).mkdir(parents=True)
        (work / name / "__init__.py").write_text(f"raise RuntimeError('the user\\'s own {name}')\n")
    (work / "models" / "barrett_mjcf").mkdir()
    (work / "models" / "barrett_mjcf" / "bh8.xml").write_text("not the hand\n")
    (work / "script.py").write_text(USER_SCRIPT)
    return work


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git to list the checkout's files")
def test_a_wheel_installs_only_twin_and_runs_beside_folders_named_like_the_repositorys(tmp_path: Path):
    src = _source_copy(tmp_path / "src")
    wheels = tmp_path / "wheels"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    subprocess.run(
        [*pip, "wheel", "--no-deps", "--no-build-isolation", "-q", str(src), "-w", str(wheels)],
        check=True, capture_output=True,
    )  # fmt: skip
    (wheel,) = wheels.glob("barrett_twin-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} == {"twin", DIST_INFO}, sorted({n.split("/")[0] for n in names})
    for part in ("bh8.xml", "scene.xml", "README.md", "LICENSE", "CHANGELOG.md"):
        assert f"twin/models/barrett_mjcf/{part}" in names
    assert "twin/hardware/bh262/urlhandler/protocol_bh8emu.py" in names
    assert "twin/experiments/compress.py" in names

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = Path(
        subprocess.run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            capture_output=True, text=True, check=True,
        ).stdout.strip()
    )  # fmt: skip
    # this environment's dependencies, as a plain path: its .pth files (the editable link) are not read
    (site / DEPS_PTH).write_text(sysconfig.get_paths()["purelib"] + "\n")
    before = set(os.listdir(site))
    subprocess.run(
        [*pip, "--python", str(python), "install", "-q", "--no-deps", "--no-index", str(wheel)],
        check=True, capture_output=True,
    )  # fmt: skip
    assert set(os.listdir(site)) - before == {"twin", DIST_INFO}, sorted(os.listdir(site))
    assert sorted(os.listdir(site)) == sorted({"twin", DIST_INFO, DEPS_PTH})

    work = _user_directory(tmp_path / "elsewhere")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    twin = str(venv / "bin" / "twin")
    version = subprocess.run([twin, "--version"], capture_output=True, text=True, cwd=work, env=env)
    assert version.returncode == 0 and version.stdout.strip() == "twin 0.1.0", version
    result = subprocess.run(
        [str(python), "script.py"], capture_output=True, text=True, cwd=work, env=env, timeout=300
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["status"] == "complete" and report["backend"] == "HardwareBackend"
    assert (work / "r" / "run.json").is_file()
    assert Path(report["model_dir"]) == site / "twin" / "models" / "barrett_mjcf"
    # the wheel's files, not the checkout's; none of the user's packages imported by the twin
    assert report["files"] and all(Path(f).is_relative_to(site / "twin") for f in report["files"])
    assert report["theirs"] == []
    assert report["mine"] == "the user's own experiments"
