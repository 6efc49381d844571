"""Frame-serving fake cameras for tests: real files that cv2.VideoCapture opens like any source.

Each frame carries a pattern that survives MJPG compression and a 2x area resize: three colour bars
(red, green, blue in RGB order, so a BGR/RGB swap shows), a grey band marking the side (left dark,
right light) and the frame number in 8 black/white blocks. `write_video` makes an MJPG .avi (read by
the FFMPEG or CV_MJPEG backend), `write_image_sequence` a lossless `frame_%04d.png` sequence (CAP_IMAGES)
and `write_video_with_gaps` an ffconcat playlist whose timestamps skip the missing numbers, so
CAP_PROP_POS_MSEC jumps where frames were lost, as a camera's timestamps would.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

WIDTH, HEIGHT = 640, 480
BITS = 8
"""Frame numbers 0-255."""
SIDE_LEVEL = {"left": 64, "right": 192}
BAR_RGB = ((255, 0, 0), (0, 255, 0), (0, 0, 255))


def pattern_rgb(number: int, side: str, width: int = WIDTH, height: int = HEIGHT) -> NDArray[np.uint8]:
    """The RGB test frame for one frame number and side."""
    if not 0 <= number < 2**BITS:
        raise ValueError(f"frame number must be in [0, {2**BITS}), got {number}")
    image = np.zeros((height, width, 3), np.uint8)
    bar_h, band_h = height // 3, height // 2
    for i, rgb in enumerate(BAR_RGB):
        image[:bar_h, i * width // 3 : (i + 1) * width // 3] = rgb
    image[bar_h:band_h] = SIDE_LEVEL[side]
    for bit in range(BITS):
        if number >> (BITS - 1 - bit) & 1:
            image[band_h:, bit * width // BITS : (bit + 1) * width // BITS] = 255
    return image


def frame_number(rgb: NDArray[np.uint8]) -> int:
    """The number encoded in a (possibly compressed and resized) test frame."""
    h, w = rgb.shape[:2]
    row = (h // 2 + h) // 2
    bits = [rgb[row, (2 * bit + 1) * w // (2 * BITS)].mean() > 128 for bit in range(BITS)]
    return sum(1 << (BITS - 1 - i) for i, on in enumerate(bits) if on)


def side_of(rgb: NDArray[np.uint8]) -> str:
    """'left' or 'right', from the grey band of a test frame."""
    h, w = rgb.shape[:2]
    level = rgb[(h // 3 + h // 2) // 2, w // 2].mean()
    return "left" if level < 128 else "right"


def bar_colours(rgb: NDArray[np.uint8]) -> list[tuple[int, int, int]]:
    """The mean colour of the three bars, in the frame's channel order."""
    h, w = rgb.shape[:2]
    return [tuple(int(v) for v in rgb[h // 6, (2 * i + 1) * w // 6]) for i in range(3)]


def write_video(path: Path, numbers: Sequence[int], side: str, fps: float = 30.0) -> Path:
    """An MJPG .avi of the given frame numbers (played back to back, whatever their values)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (WIDTH, HEIGHT))
    if not writer.isOpened():
        raise RuntimeError(f"this OpenCV cannot write MJPG to {path}")
    try:
        for number in numbers:
            writer.write(cv2.cvtColor(pattern_rgb(number, side), cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
    return path


def write_image_sequence(directory: Path, numbers: Sequence[int], side: str) -> str:
    """PNG files frame_0000.png, frame_0001.png, ... of the given numbers; returns the %04d pattern."""
    directory.mkdir(parents=True, exist_ok=True)
    for index, number in enumerate(numbers):
        bgr = cv2.cvtColor(pattern_rgb(number, side), cv2.COLOR_RGB2BGR)
        cv2.imwrite(str(directory / f"frame_{index:04d}.png"), bgr)
    return str(directory / "frame_%04d.png")


def write_video_with_gaps(directory: Path, numbers: Sequence[int], side: str, fps: float = 30.0) -> Path:
    """An ffconcat playlist of MJPG segments whose timestamps are number / fps: a missing number
    leaves a gap in CAP_PROP_POS_MSEC (FFMPEG backend only)."""
    directory.mkdir(parents=True, exist_ok=True)
    runs: list[list[int]] = []
    for number in numbers:
        if runs and number == runs[-1][-1] + 1:
            runs[-1].append(number)
        else:
            runs.append([number])
    lines = ["ffconcat version 1.0"]
    for i, run in enumerate(runs):
        segment = write_video(directory / f"{side}_segment_{i}.avi", run, side, fps)
        lines.append(f"file {segment.name}")
        if i + 1 < len(runs):
            lines.append(f"duration {(runs[i + 1][0] - run[0]) / fps:.6f}")
    playlist = directory / f"{side}.ffconcat"
    playlist.write_text("\n".join(lines) + "\n")
    return playlist
