"""A Ctrl-C while a 10^6-triangle scan is decimated and meshed (issue 37 item 6): that C code runs in a
child process the CLI kills, so the command ends at once with one line, and no process is left behind."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from tests.procfs import child_pids

TWIN = [sys.executable, "-m", "twin.cli"]


def _uv_egg_stl(path: Path, segments: int = 1000, rings: int = 502) -> Path:
    """A binary STL of an egg (64 x 52 x 44 mm) with 2 x segments x (rings - 2) triangles: 10^6 by
    default, as a fine scan leaves it. Its 1,000-triangle pole fans keep quadric decimation busy ~10 s."""
    theta = np.linspace(0, np.pi, rings)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    waist = 1 + 0.15 * np.cos(t)
    ring = np.c_[(32 * waist * np.sin(t) * np.cos(p)).ravel(), (26 * waist * np.sin(t) * np.sin(p)).ravel()]
    points = np.vstack([np.c_[ring, (22 * np.cos(t)).ravel()], [0, 0, 22], [0, 0, -22]])
    top, bottom, n = len(points) - 2, len(points) - 1, len(theta)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n - 1), np.arange(segments), indexing="ij"))
    jj = np.arange(segments)

    def at(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return i * segments + j % segments

    triangles = np.concatenate([
        np.c_[at(i, j), at(i + 1, j), at(i, j + 1)], np.c_[at(i, j + 1), at(i + 1, j), at(i + 1, j + 1)],
        np.c_[np.full(segments, top), at(0, jj), at(0, jj + 1)],
        np.c_[np.full(segments, bottom), at(n - 1, jj + 1), at(n - 1, jj)],
    ])  # fmt: skip
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    data = np.zeros(len(triangles), dtype=record)
    data["corners"] = points[triangles]
    with path.open("wb") as f:
        f.write(b"a fine scan".ljust(80, b" ") + np.uint32(len(triangles)).tobytes() + data.tobytes())
    return path


def _alive(pid: int) -> bool:
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc for the child processes")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupt_while_a_huge_scan_is_meshed_ends_the_command_in_one_line(tmp_path: Path, sig: int):
    big = _uv_egg_stl(tmp_path / "big.stl")
    assert big.stat().st_size == 84 + 50 * 1_000_000
    proc = subprocess.Popen(
        [*TWIN, "run", "compress", "--object-mesh", str(big), "--duration", "1", "--out", "r",
         "--no-progress"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    lines: queue.Queue[str] = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(line) for line in proc.stderr], daemon=True)  # type: ignore[union-attr]
    reader.start()
    try:
        first = lines.get(timeout=120)  # the progress line, printed once the meshing worker exists
        assert "1,000,000 triangles, decimating" in first, first
        workers = child_pids(proc.pid)
        assert workers, "no meshing worker"
        proc.send_signal(sig)
        proc.wait(timeout=60)  # a hang guard, not a timing
        out = proc.stdout.read()  # type: ignore[union-attr]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=10)
    rest = []
    while not lines.empty():
        rest.append(lines.get())
    err = "".join(rest)
    assert proc.returncode == 130, (proc.returncode, err)
    assert "Traceback" not in err and out == "", err
    assert len(rest) == 1 and rest[0].startswith("twin: interrupted;"), err
    assert not [pid for pid in workers if _alive(pid)], "a meshing worker outlived the command"
    assert sorted(os.listdir(tmp_path)) == ["big.stl"]  # nothing written: the run had not started
