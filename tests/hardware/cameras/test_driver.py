"""StereoCapture on real cv2.VideoCapture sources: MJPG videos, PNG sequences and ffconcat playlists."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from twin.hardware.backend import WallClock
from twin.hardware.cameras import fake
from twin.hardware.cameras.driver import (
    CameraMissingError,
    CameraTimeoutError,
    StereoCapture,
    StereoCaptureConfig,
    available_backends,
)

from twin.interface.errors import ConfigError, DeviceError, DeviceNotConnectedError

TIMEOUT_S = 0.3


def capture(left: object, right: object, **kw: object) -> StereoCapture:
    config = StereoCaptureConfig(left=str(left), right=str(right), timeout_s=TIMEOUT_S, **kw)
    return StereoCapture(config, WallClock())


def read_all(cam: StereoCapture, n: int) -> list[tuple[int, int]]:
    frames = [cam.read() for _ in range(n)]
    return [(fake.frame_number(f.left), fake.frame_number(f.right)) for f in frames]


def assert_one_line(exc: BaseException, *parts: str) -> None:
    message = str(exc)
    assert "\n" not in message
    for part in parts:
        assert part in message, message


def make_sources(tmp_path: Path, kind: str, n_left: int, n_right: int) -> tuple[str, str]:
    if kind == "avi":
        return (
            str(fake.write_video(tmp_path / "left.avi", range(n_left), "left")),
            str(fake.write_video(tmp_path / "right.avi", range(n_right), "right")),
        )
    return (
        fake.write_image_sequence(tmp_path / "left", range(n_left), "left"),
        fake.write_image_sequence(tmp_path / "right", range(n_right), "right"),
    )


@pytest.mark.parametrize("kind, backend", [("avi", "any"), ("avi", "ffmpeg"), ("png", "images")])
def test_frames_arrive_in_order_paired_rgb_and_resized(tmp_path, kind, backend):
    left, right = make_sources(tmp_path, kind, 12, 12)
    with capture(left, right, backend=backend) as cam:
        frames = [cam.read() for _ in range(12)]
        diag = cam.diagnostics()
    numbers = [(fake.frame_number(f.left), fake.frame_number(f.right)) for f in frames]
    assert numbers == [(i, i) for i in range(12)]
    times = [f.t_s for f in frames]
    assert times == sorted(times) and times[0] >= 0
    for f in frames:
        for image, side in ((f.left, "left"), (f.right, "right")):
            assert image.shape == (240, 320, 3) and image.dtype == np.uint8
            assert fake.side_of(image) == side
            red, green, blue = fake.bar_colours(image)  # RGB order: a BGR frame would start with blue
            assert red[0] > 200 and red[2] < 60
            assert green[1] > 200 and max(green[0], green[2]) < 60
            assert blue[2] > 200 and blue[0] < 60
    assert diag["pairs"] == 12 and diag["dropped_frames"] == 0 and diag["resyncs"] == 0
    assert diag["left"]["frame_size"] == (640, 480)


def test_source_running_out_fails_within_the_timeout(tmp_path):
    left, right = make_sources(tmp_path, "avi", 3, 3)
    with capture(left, right) as cam:
        read_all(cam, 3)
        start = time.monotonic()
        with pytest.raises(CameraTimeoutError) as err:
            cam.read()
        elapsed = time.monotonic() - start
        diag = cam.diagnostics()
    assert TIMEOUT_S <= elapsed < TIMEOUT_S + 0.4
    assert_one_line(err.value, "left camera", "right camera", "left.avi", "within 0.3 s", "end of a file")
    assert diag["timeouts"] == 1 and diag["left"]["failed_grabs"] > 0
    assert diag["dropped_frames"] == 0  # nothing was lost: both simply ended


def test_length_mismatch_is_a_dropped_frame_and_names_the_short_camera(tmp_path):
    left, right = make_sources(tmp_path, "png", 6, 4)
    with capture(left, right) as cam:
        assert read_all(cam, 4) == [(i, i) for i in range(4)]
        with pytest.raises(CameraTimeoutError) as err:
            cam.read()
        diag = cam.diagnostics()
    assert_one_line(err.value, "right camera", "right/frame_%04d.png")
    assert "left camera" not in str(err.value)
    assert diag["left"]["dropped_frames"] == 1  # frame 4 of the left had no partner
    assert diag["right"]["failed_grabs"] > 0 and diag["left"]["failed_grabs"] == 0


def test_timestamp_gap_is_counted_and_the_pair_resynchronised(tmp_path):
    left = fake.write_video_with_gaps(tmp_path, range(10), "left")
    right = fake.write_video_with_gaps(tmp_path, [0, 1, 2, 3, 4, 7, 8, 9], "right")
    with capture(left, right) as cam:
        numbers = read_all(cam, 6)
        diag = cam.diagnostics()
    assert numbers == [(0, 0), (1, 1), (2, 2), (3, 3), (4, 4), (7, 7)]
    assert diag["right"]["dropped_frames"] == 2 and diag["right"]["counter_gaps"] == 1
    assert diag["left"]["dropped_frames"] == 2 and diag["resyncs"] == 2  # left 5 and 6 skipped
    assert diag["dropped_frames"] == 4 and diag["right"]["reports_pos_msec"]


def test_gap_without_resync_still_shows_in_the_counters(tmp_path):
    left = fake.write_video_with_gaps(tmp_path, range(8), "left")
    right = fake.write_video_with_gaps(tmp_path, [0, 1, 2, 5, 6, 7], "right")
    with capture(left, right, resync=False) as cam:
        numbers = read_all(cam, 4)
        diag = cam.diagnostics()
    assert numbers[3] == (3, 5)  # out of step: the counters say so
    assert diag["right"]["dropped_frames"] == 2 and diag["resyncs"] == 0


def test_missing_camera_is_a_one_line_error_naming_it(tmp_path):
    left, _ = make_sources(tmp_path, "avi", 2, 0)
    cam = capture(left, tmp_path / "nope.avi")
    with pytest.raises(CameraMissingError) as err:
        cam.connect()
    assert_one_line(err.value, "right camera", "nope.avi")
    assert not cam.is_connected
    if "v4l2" not in available_backends():
        return
    cam = StereoCaptureConfig(left=97, right=left, backend="v4l2", timeout_s=TIMEOUT_S)
    with pytest.raises(DeviceError) as err:
        StereoCapture(cam, WallClock()).connect()
    assert_one_line(err.value, "left camera", "device 97", "v4l2")


@pytest.mark.parametrize("backend", ["firewire", "gstreamer"])
def test_backend_missing_from_this_build_is_named(tmp_path, backend):
    if backend in available_backends():
        pytest.skip(f"this OpenCV has {backend}")
    cam = capture(0, 1, backend=backend)
    with pytest.raises(CameraMissingError) as err:
        cam.connect()
    assert_one_line(err.value, f"no {backend} backend")


def test_config_validation_and_life_cycle(tmp_path):
    with pytest.raises(ConfigError):
        StereoCaptureConfig(left=0, right=1, backend="dc1394")
    with pytest.raises(ConfigError):
        StereoCaptureConfig(left=0, right=1, width=300, height=240)
    assert StereoCaptureConfig(left="0", right=" 1 ").right == 1
    left, right = make_sources(tmp_path, "avi", 2, 2)
    cam = capture(left, right)
    assert cam.spec.channels["left"].shape == (240, 320, 3) and cam.spec.rate_hz == 30.0
    with pytest.raises(DeviceNotConnectedError):
        cam.read()
    with cam:
        cam.read()
    cam.disconnect()  # twice is fine
    with cam:  # reconnecting reopens the files from the start
        assert read_all(cam, 2) == [(0, 0), (1, 1)]
        assert cam.diagnostics()["pairs"] == 2
