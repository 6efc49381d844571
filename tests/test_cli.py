"""The `twin` CLI end to end: real runs on disk, read back with the reader and Rerun's own API,
and bad input that ends in one line, a non-zero exit and nothing written."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from twin.cli import main
from twin.recording import open_run
from twin.sim.foam import LIBRARY

TWIN = [sys.executable, "-m", "twin.cli"]


def twin(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    env.pop("DISPLAY", None)
    return subprocess.run([*TWIN, *args], capture_output=True, text=True, env=env, timeout=600)


def test_objects_json_lists_the_library():
    result = twin("objects", "--json")
    assert result.returncode == 0, result.stderr
    objects = json.loads(result.stdout)
    assert {o["name"] for o in objects} == set(LIBRARY)
    assert {o["shape"] for o in objects} >= {"block", "cylinder", "sphere"}
    assert {o["stiffness_class"] for o in objects} >= {"soft", "medium", "firm"}
    assert all(o["young_pa"] > 0 and 0 <= o["poisson"] < 0.5 for o in objects)


def test_run_compress_end_to_end_then_info_and_rrd(tmp_path: Path):
    out = tmp_path / "run"
    result = twin(
        "run", "compress", "--object", "soft_block", "--duration", "3", "--seed", "4",
        "--young", "20e3", "--out", str(out), "--no-progress",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    info = json.loads(twin("info", str(out), "--json").stdout)
    assert info["status"] == "complete"
    streams = {s["name"]: s for s in info["streams"]}
    hand = streams["hand"]
    assert hand["rate_hz"] == 30 and hand["measured_rate_hz"] == pytest.approx(30, rel=0.01)
    assert hand["samples"] == 91
    assert {f["kind"] for f in hand["fields"].values()} == {"raw", "physical"}
    assert hand["fields"]["strain_counts"]["unit"] == "counts"
    assert hand["fields"]["torque_nm"]["unit"] == "N*m"
    meta = info["metadata"]
    assert meta["object"]["young_pa"] == 20e3 and meta["seed"] == 4
    assert meta["calibration"]["strain_torque_eq2"]["slope_nm"] == 0.0085
    assert "--young" in meta["command_line"]
    # The .rrd reads back with Rerun's own API: the plotted positions are the recorded ones.
    from twin.viz.rerun_log import read_rrd_entities, read_rrd_scalars

    entities = read_rrd_entities(out / "run.rrd")
    assert any("flex" in e for e in entities)
    times, values = read_rrd_scalars(out / "run.rrd", "/plots/hand/position_counts")
    recorded = open_run(out).stream("hand")
    assert len(times) == len(recorded)
    assert np.allclose(values, recorded["position_counts"][:, :3])


@pytest.mark.parametrize("name", sorted(LIBRARY))
def test_every_library_foam_runs_10_s_headless(name: str, tmp_path: Path):
    out = tmp_path / name
    assert (
        main(["run", "compress", "--object", name, "--duration", "10", "--out", str(out), "--no-progress"])
        == 0
    )
    run = open_run(out)
    assert run.status == "complete"
    assert run.metadata["mujoco_warnings"] == {}
    assert run.metadata["final_phase"] == "compress"
    torque = run.stream("hand")["torque_nm"]
    # Far above the 0.005 N*m gauge noise: every finger still squeezes the foam through the last 2 s.
    assert (torque[-60:] > 0.05).all()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--object", "pillow"], "unknown object 'pillow'"),
        (["--young", "-5"], "Young's modulus must be > 0"),
        (["--poisson", "0.5"], "Poisson ratio must be in [0, 0.5)"),
        (["--size-mm", "200", "200", "50"], "does not fit in the hand"),
        (["--duration", "0"], "--duration must be > 0"),
        (["--backend", "hardware"], "no BH8 hand is configured"),
    ],
)
def test_bad_input_one_line_nonzero_nothing_written(args, message, tmp_path: Path):
    out = tmp_path / "run"
    result = twin("run", "compress", *args, "--out", str(out), "--no-progress")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twin: error:") and message in lines[0], result.stderr
    assert not out.exists()


def test_unwritable_or_used_out_is_refused_before_simulating(tmp_path: Path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    result = twin("run", "compress", "--out", str(blocker / "run"), "--no-progress")
    assert result.returncode == 2 and "is not a directory" in result.stderr
    used = tmp_path / "used"
    used.mkdir()
    (used / "keep.txt").write_text("precious")
    result = twin("run", "compress", "--out", str(used), "--no-progress")
    assert result.returncode == 2 and "not empty" in result.stderr
    assert sorted(p.name for p in used.iterdir()) == ["keep.txt"]


def test_ctrl_c_marks_the_run_interrupted_and_keeps_the_data(tmp_path: Path):
    out = tmp_path / "run"
    env = {**os.environ, "MUJOCO_GL": "egl"}
    cmd = [*TWIN, "run", "compress", "--duration", "120", "--out", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (out / "streams").exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr
    run = open_run(out)
    assert run.status == "interrupted"
    assert len(run.stream("hand")) > 10
    assert not run.truncated


def test_info_and_view_on_something_that_is_not_a_run(tmp_path: Path):
    result = twin("info", str(tmp_path))
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    result = twin("view", str(tmp_path))
    assert result.returncode == 2 and "no Rerun recording" in result.stderr


def test_sigkill_mid_run_loses_at_most_about_a_second(tmp_path: Path):
    out = tmp_path / "run"
    env = {**os.environ, "MUJOCO_GL": "egl"}
    cmd = [*TWIN, "run", "compress", "--duration", "300", "--out", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not (out / "streams" / "hand.arrows").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(3.0)
    killed_at = time.time()
    proc.kill()
    proc.wait(timeout=30)
    # Data reached the OS moments before the kill (the writer flushes every 0.25 s of run or wall time).
    assert killed_at - (out / "streams" / "hand.arrows").stat().st_mtime < 1.0
    run = open_run(out)
    assert run.status == "running"  # never closed: it does not claim to be complete
    hand = run.stream("hand")
    assert len(hand) > 30
    # Contiguous from t = 0: nothing before the cut is missing.
    assert hand.t_s[0] == 0.0
    assert np.diff(hand.t_s).max() < 2.5 / 30
    # Every stream reached about the same instant: at most ~1 s of run time was lost from any.
    ends = {name: run.stream(name).t_s[-1] for name in ("hand", "command", "truth")}
    assert max(ends.values()) - min(ends.values()) < 1.0
