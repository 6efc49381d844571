"""File-system faults through the real `twin` command (issue 37): a full disk (a small tmpfs), a read-only
one, /dev/full as the output. One line naming the path and the reason, a non-zero exit, a status that
tells the truth, nothing half-written. Mounting needs root (CAP_SYS_ADMIN): elsewhere these skip."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from twin.recording import open_run

TWIN = [sys.executable, "-m", "twin.cli"]


def twin(*args: str, cwd: Path, timeout: float = 300, **kwargs) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    env.pop("DISPLAY", None)
    argv = [*TWIN, *args]
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, env=env, timeout=timeout, **kwargs)


def one_line(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 2, (result.returncode, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twin: error: "), result.stderr
    return lines[0]


def _mount(where: Path, *options: str) -> None:
    where.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", ",".join(options), "tmpfs", str(where)],
                          capture_output=True, text=True)  # fmt: skip
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip()})")


@pytest.fixture
def mounts(tmp_path: Path) -> Iterator[dict[str, Path]]:
    """A 5 MB tmpfs (`full`) and a read-only one (`ro`), unmounted at the end."""
    made = []
    try:
        _mount(tmp_path / "full", "size=5m")
        made.append(tmp_path / "full")
        _mount(tmp_path / "ro", "size=1m", "ro")
        made.append(tmp_path / "ro")
        yield {"full": tmp_path / "full", "ro": tmp_path / "ro"}
    finally:
        for where in made:
            subprocess.run(["umount", "-l", str(where)], check=False)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short real sim run to export and analyse."""
    root = tmp_path_factory.mktemp("run")
    result = twin("run", "compress", "--duration", "1", "--out", "run", "--no-progress", cwd=root)
    assert result.returncode == 0, result.stderr
    return root / "run"


@pytest.mark.slow
def test_a_disk_that_fills_mid_run_ends_the_run_failed_in_one_line(mounts: dict[str, Path], tmp_path: Path):
    out = mounts["full"] / "run"
    result = twin("run", "compress", "--duration", "60", "--out", str(out), "--no-progress", cwd=tmp_path)
    line = one_line(result)
    assert "No space left on device" in line and str(out) in line, line
    run = open_run(out)
    assert run.status == "failed" and "No space left on device" in run.info["error"]
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []  # no temp or reserve left


def test_read_only_places_are_refused_before_any_work(mounts: dict[str, Path], run: Path, tmp_path: Path):
    ro = mounts["ro"]
    cases = [
        ["export", str(run), "--out", str(ro / "ds")],
        ["export", str(run), "--format", "parquet", "--out", str(ro / "ds")],
        ["sweep", "--objects", "block", "--trajectories", "1", "--out", str(ro / "dataset"), "--no-progress"],
        ["calibrate", "cameras", "--out", str(ro / "cal.json")],
        ["emulate", "hand", "--rig-file", str(ro / "rig.toml"), "--duration", "1"],
        ["identify", str(run), "--out", str(ro / "id"), "--no-progress"],
        ["fit", str(run), "--out", str(ro / "fit"), "--no-progress"],
        ["run", "compress", "--duration", "1", "--out", str(ro / "run"), "--no-progress"],
    ]
    for argv in cases:
        line = one_line(twin(*argv, cwd=tmp_path, timeout=60))  # refused before minutes of work
        assert "Read-only file system" in line, (argv, line)
    assert list(ro.iterdir()) == []


def test_a_full_disk_export_leaves_nothing_and_the_next_try_works(mounts: dict[str, Path], tmp_path: Path):
    """A LeRobot export into the last 16 KB of a disk: one line, no half dataset (the next try into the
    same --out is not refused), and once there is room the same command works."""
    full = mounts["full"]
    (full / "filler").write_bytes(b"\0" * (5 * 2**20 - 16 * 1024))
    runs = []
    for k in range(2):
        runs.append(str(tmp_path / f"r{k}"))
        result = twin("run", "compress", "--duration", "2", "--out", runs[-1], "--no-progress", cwd=tmp_path)
        assert result.returncode == 0, result.stderr
    line = one_line(twin("export", *runs, "--out", str(full / "ds"), cwd=tmp_path))
    assert "No space left on device" in line, line
    assert sorted(p.name for p in full.iterdir()) == ["filler"]
    (full / "filler").unlink()
    assert twin("export", *runs, "--out", str(full / "ds"), cwd=tmp_path).returncode == 0


def test_a_rig_file_on_a_full_disk_is_one_line(mounts: dict[str, Path], tmp_path: Path):
    full = mounts["full"]
    (full / "filler").write_bytes(b"\0" * (5 * 2**20 - 4096))
    result = twin("emulate", "rig", "--no-cameras", "--rig-file", str(full / "rig.toml"), "--duration", "1",
                  cwd=tmp_path, timeout=120)  # fmt: skip
    line = one_line(result)
    assert "No space left on device" in line, line


def test_a_run_whose_output_is_dev_full_says_so_and_its_status_is_true(tmp_path: Path):
    argv = [*TWIN, "run", "compress", "--duration", "0.5", "--out", "r", "--no-progress"]
    with open("/dev/full", "w") as full:
        result = subprocess.run(argv, cwd=tmp_path, stdout=full, stderr=subprocess.PIPE, text=True)
    assert "<stdout>: No space left on device" in one_line(result)
    assert json.loads((tmp_path / "r" / "run.json").read_text())["status"] == "complete"  # it did complete
