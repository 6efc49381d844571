"""Runs with cameras end to end through the CLI: the stereo stream, the fused surface in the hand
frame, the tactile fill-in once the fingers close, and bad vision input refused before anything runs."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from twin.recording import open_run
from twin.vision.fusion import TACTILE, VISION
from twin.vision.pipeline import STAGES, decode_jpeg

TWIN = [sys.executable, "-m", "twin.cli"]


def twin(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    return subprocess.run([*TWIN, *args], capture_output=True, text=True, env=env, timeout=600)


@pytest.fixture(scope="module")
def camera_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cameras") / "run"
    result = twin("run", "compress", "--cameras", "--duration", "4", "--out", str(out), "--no-progress")
    assert result.returncode == 0, result.stderr
    return out


@pytest.mark.slow
def test_stereo_stream_at_30_fps_with_frames_and_surface(camera_run: Path):
    run = open_run(camera_run)
    stereo = run.stream("stereo")
    assert len(stereo) == 121 and stereo.measured_rate_hz() == pytest.approx(30.0, rel=0.01)
    left = decode_jpeg(stereo["left_jpeg"][0])
    assert left.shape == (240, 320, 3) and left.dtype == np.uint8
    info = json.loads((camera_run / "run.json").read_text())
    files = info["metadata"]["calibration_files"]
    assert files["stereo_calibration"] == "calibration/stereo_calibration.json"
    assert stereo["process_ms"].shape == (121, len(STAGES))
    for k in range(len(stereo)):
        points, source, triangles = stereo["points_m"][k], stereo["point_source"][k], stereo["triangles"][k]
        assert len(points) == len(source) and (triangles < len(points)).all()
        vision = points[source == VISION]
        assert len(vision) > 100
        # The foam (60 x 60 x 70 mm) sits on the palm (z = 75 mm): the cloud's middle is on it.
        lo, hi = np.percentile(vision, 25, axis=0), np.percentile(vision, 75, axis=0)
        assert (lo > [-0.045, -0.045, 0.07]).all() and (hi < [0.045, 0.045, 0.16]).all(), (k, lo, hi)


def test_tactile_points_fill_in_once_the_fingers_grasp(camera_run: Path):
    run = open_run(camera_run)
    stereo, tactile = run.stream("stereo"), run.stream("tactile")
    n_tactile = np.array([(s == TACTILE).sum() for s in stereo["point_source"]])
    assert n_tactile[:15].sum() == 0  # open hand: nothing pressed (the palm under the foam is, below)
    grasped = stereo.t_s > 3.0
    assert (n_tactile[grasped] >= 4).all()
    assert tactile["active_taxels"][-1][:3].min() >= 1  # every fingertip pad is pressed
    last = stereo["points_m"][-1][stereo["point_source"][-1] == TACTILE]
    # Finger and palm contacts lie around the foam: its footprint and height, with a finger's margin.
    assert (np.abs(last[:, :2]) < 0.03 + 0.012).all()
    assert ((last[:, 2] > 0.070) & (last[:, 2] < 0.150)).all()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--cameras", "--bbox", "10,10,0,5"], "empty"),
        (["--cameras", "--bbox", "10,10,5"], "expected x,y,w,h"),
        (["--cameras", "--bbox", "300,200,60,60"], "inside the 320x240 image"),
        (["--bbox", "10,10,20,20"], "need --cameras"),
        (["--cameras", "--stereo-calibration", "/nonexistent/stereo.json"], "/nonexistent/stereo.json"),
    ],
)
def test_bad_vision_input_one_line_nothing_written(args, message, tmp_path: Path):
    out = tmp_path / "run"
    result = twin("run", "compress", *args, "--out", str(out), "--no-progress")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twin: error:") and message in lines[0], result.stderr
    assert not out.exists()


def test_corrupt_calibration_file_names_file_and_line(tmp_path: Path):
    bad = tmp_path / "stereo.json"
    bad.write_text('{"format": "barrett-twin stereo calibration v1",\n  "left": [1, 2,,]}\n')
    out = tmp_path / "run"
    result = twin("run", "compress", "--cameras", "--stereo-calibration", str(bad), "--out", str(out))
    assert result.returncode == 2 and f"{bad}:2:" in result.stderr, result.stderr
    assert not out.exists()


@pytest.mark.slow
def test_reconstruction_accuracy_against_the_twin_truth(camera_run: Path):
    """Acceptance: the deforming block reconstructed within 1.5 mm (median) covering >= 60 % of its
    visible surface, scored per frame against the true surface at that instant and summarized per run."""
    run = open_run(camera_run)
    truth = run.stream("stereo_truth")
    assert len(truth) == 41 and truth.measured_rate_hz() == pytest.approx(10.0, rel=0.01)  # every 3rd
    summary = run.metadata["stereo_truth"]
    assert summary["frames"] == len(truth)
    assert summary["median_mm"] <= 1.5 and summary["coverage"] >= 0.6, summary
    grasped = truth.t_s > 2.5  # fingers closed on the foam, which they partly hide
    assert grasped.sum() > 10
    ok = (truth["median_mm"] <= 1.5) & (truth["coverage"] >= 0.6)
    assert ok[grasped].mean() >= 0.9, (truth["median_mm"][grasped], truth["coverage"][grasped])
    assert (truth["visible_px"][grasped] < truth["visible_px"][0]).all()  # the occlusion is real


@pytest.mark.slow
def test_runs_with_cameras_are_deterministic_for_a_seed():
    """Frames render on their own thread and reconstruct on another; the result must not depend on it."""
    from twin.experiments.compress import CompressController

    from twin.rig import Rig
    from twin.sim.backend import SimBackend
    from twin.sim.foam import get_object
    from twin.vision.pipeline import StereoPipeline
    from twin.vision.reconstruct import Rectifier

    def scores(seed: int) -> list[dict]:
        backend = SimBackend(get_object("block"), seed=seed, stereo=True)
        backend.connect()
        try:
            calibration = backend.stereo.calibration()
            pipeline = StereoPipeline(calibration, backend.object_box(Rectifier(calibration)))
            rig = Rig(backend, stereo_pipeline=pipeline)
            rig.run(CompressController(), 2.5)
            return rig.surface_scores
        finally:
            backend.disconnect()

    first, second, other = scores(3), scores(3), scores(4)
    assert len(first) == 26 and first == second
    assert first != other  # the seed reaches the cameras' noise


@pytest.mark.slow
def test_ctrl_c_keeps_the_frames_the_vision_worker_finished(tmp_path: Path):
    import signal
    import time

    out = tmp_path / "run"
    env = {**os.environ, "MUJOCO_GL": "egl"}
    cmd = [*TWIN, "run", "compress", "--cameras", "--duration", "120", "--out", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (out / "streams" / "stereo.arrows").exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(3.0)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    run = open_run(out)
    assert run.status == "interrupted" and not run.truncated
    stereo, hand = run.stream("stereo"), run.stream("hand")
    # ~3 s of a run: how many frames that is depends on the machine's load (20 on a busy CI runner).
    assert len(stereo) >= 10
    assert abs(len(stereo) - len(hand)) <= 2  # the vision worker's backlog was recorded, not lost
    assert np.all(np.diff(stereo.t_s) > 0)
    assert run.metadata["stereo_truth"]["frames"] == len(run.stream("stereo_truth"))


def test_hardware_cameras_without_a_box_are_refused_before_anything_is_written(tmp_path: Path):
    from twin.hardware.rig_config import rig_toml

    from twin.sim.backend import SimBackend

    SimBackend(None, stereo=True).stereo.calibration().save(tmp_path / "stereo.json")
    rig = tmp_path / "rig.toml"
    rig.write_text(rig_toml("loop://", stereo=("0", "1"), stereo_calibration="stereo.json"))
    out = tmp_path / "run"
    result = twin(
        "run", "compress", "--backend", "hardware", "--rig", str(rig), "--cameras", "--out", str(out)
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "--bbox" in lines[0], result.stderr
    assert not out.exists()


@pytest.mark.slow
def test_the_viewer_colours_the_stereo_points_by_their_error_to_the_truth(camera_run: Path):
    """Sim camera runs: every stereo cloud in the .rrd is coloured by each point's distance to the true
    surface (not by the image). Read back through the colour map, the points' median error is the
    frame's recorded stereo_truth median (the .rrd keeps every 2nd row and column of the cloud)."""
    from twin.viz.rerun_log import CLOUD_ENTITY, POINT_ERROR_SCALE_MM, error_colors, read_rrd_points

    lut_mm = np.linspace(0.0, POINT_ERROR_SCALE_MM, 501)
    lut = error_colors(lut_mm).astype(int)
    truth = open_run(camera_run).stream("stereo_truth")
    clouds = read_rrd_points(camera_run / "run.rrd", CLOUD_ENTITY)
    assert len(clouds) >= 15  # 4 s at 5 Hz
    for t, points, colors in clouds:
        assert len(points) == len(colors) > 100
        rgb = colors[:, :3].astype(int)
        distance = np.abs(rgb[:, None, :] - lut[None, :, :]).sum(axis=2)
        assert distance.min(axis=1).max() <= 3, "a point's colour is not on the error scale"
        error_mm = lut_mm[distance.argmin(axis=1)]
        k = int(np.argmin(np.abs(truth.t_s - t)))
        assert abs(truth.t_s[k] - t) < 1e-6, "a cloud was logged for a frame that was not scored"
        median = truth["median_mm"][k]
        assert np.median(error_mm) == pytest.approx(median, abs=0.1 + 0.15 * median)
