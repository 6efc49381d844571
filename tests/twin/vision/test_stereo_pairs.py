"""A rig of several stereo pairs: a run records each (`stereo` for the first, `stereo_<placement>` for the
others), each pair sees its own side of the object, and a further pair leaves the first's record as it was."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from twin.recording import open_run
from twin.vision.fusion import VISION
from twin.vision.pipeline import decode_jpeg
from twin.vision.strain_record import observe_run, opposite_pair_streams

TWIN = [sys.executable, "-m", "twin.cli"]


def twin(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    return subprocess.run([*TWIN, *args], capture_output=True, text=True, env=env, timeout=600)


def compress(out: Path, *args: str) -> Path:
    result = twin(
        "run", "compress", "--cameras", "--duration", "1", "--out", str(out), "--no-progress", *args
    )
    assert result.returncode == 0, result.stderr
    return out


@pytest.mark.slow
def test_two_opposite_pairs_are_both_recorded_each_seeing_its_own_face(tmp_path: Path):
    two = open_run(compress(tmp_path / "two", "--camera-placement", "lateral,opposite"))
    assert {"stereo", "stereo_opposite"} <= set(two.streams)
    first, second = two.stream("stereo"), two.stream("stereo_opposite")
    assert len(first) == len(second) == 31
    np.testing.assert_array_equal(first.t_s, second.t_s)  # triggered together
    info = json.loads((tmp_path / "two" / "run.json").read_text())["metadata"]
    assert info["stereo_placements"] == ["lateral", "opposite"]
    assert info["calibration_files"]["stereo_calibration_opposite"] == (
        "calibration/stereo_calibration_opposite.json"
    )
    assert decode_jpeg(second["left_jpeg"][0]).shape == (240, 320, 3)
    # The block (60 mm wide, centred on the palm axis): `lateral` stands on the palm's +x side, `opposite`
    # on its -x side; each pair's points lie on its own half, its face ~30 mm out.
    for k in (0, len(first) - 1):
        plus = first["points_m"][k][first["point_source"][k] == VISION]
        minus = second["points_m"][k][second["point_source"][k] == VISION]
        assert len(plus) > 100 and len(minus) > 100
        assert np.percentile(plus[:, 0], 90) == pytest.approx(0.03, abs=0.004)
        assert np.percentile(minus[:, 0], 10) == pytest.approx(-0.03, abs=0.004)
    # The strain reader finds the two opposite pairs by their calibration; a 1 s run has no squeeze yet.
    assert opposite_pair_streams(two) == ("stereo", "stereo_opposite")
    with pytest.raises(ValueError, match="never reached the squeeze"):
        observe_run(two, 0.07, 0.075)
    # The first pair records what a one-pair run of the same seed records: the second changes nothing.
    one = open_run(compress(tmp_path / "one"))
    assert "stereo_opposite" not in one.streams and opposite_pair_streams(one) is None
    for field in ("left_jpeg", "points_m", "triangles"):
        for a, b in zip(one.stream("stereo")[field], first[field], strict=True):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--cameras", "--camera-placement", "lateral,nowhere"], "camera placements lateral,nowhere"),
        (["--cameras", "--camera-placement", "lateral,lateral"], "at most once"),
        (["--camera-placement", "opposite"], "needs --cameras"),
    ],
)
def test_bad_camera_placements_one_line_nothing_written(args, message, tmp_path: Path):
    out = tmp_path / "run"
    result = twin("run", "compress", *args, "--out", str(out), "--no-progress")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twin: error:") and message in lines[0], result.stderr
    assert not out.exists()
