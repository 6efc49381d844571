"""One run as frames on the hand's rate grid: what a LeRobot episode holds.

A LeRobot dataset is sampled on a grid: frame k of an episode is at `timestamp = k / fps` (what its
recorder writes, what `delta_timestamps` and its video decoder look frames up by). The hand's readings
are near that grid, not on it: in the sim they sit on the 2 ms physics step (up to 0.7 ms off at
30 Hz), on hardware wherever the serial loop took them (a loaded host drifts, a slow loop skips). So
the frames are resampled: frame k holds the latest hand reading taken by `t0 + (k + 1/2) / fps` (t0:
the first reading), i.e. the reading nearest its grid instant, the later of two equally near. Where
the hand kept its rate every reading is one frame, in order (every sim run); where it fell behind, a
frame repeats the previous frame's reading (`held`), and where it ran fast a reading is left out
(`unused`); the reading's own time on the run clock stays with each frame (`t_s`).

Beside each frame's reading: the command the rig sent in answer to it (the first command recorded at
or after the reading and before the next one; where there is none the previous command is held), and
the latest tactile scan and stereo pair at or before the reading (zero-order hold), so no frame sees a
sample from its future.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twin.interface.devices import MOTOR_LABELS
from twin.interface.errors import ConfigError
from twin.recording import Run, open_run

STATE_NAMES = (
    *(f"{m}.position_counts" for m in MOTOR_LABELS),
    *(f"{m}.velocity_counts" for m in MOTOR_LABELS),
    *(f"{m}.strain_counts" for m in MOTOR_LABELS[:3]),
)
"""observation.state, in the units the hand reports (encoder counts, velocity counts, strain 0-255)."""
ACTION_NAMES = tuple(f"{m}.position_counts" for m in MOTOR_LABELS)
"""action: the set points sent (encoder counts), after the safety layer and the device's clipping."""
_TIE_S = 1e-9
"""Two instants on the run clock this close are one (sums of float steps)."""


@dataclass
class EpisodeFrames:
    """A run's frames on the grid: each frame's reading time, state, action, and where recorded tactile
    counts and JPEG pairs; `held` frames repeat the previous frame's reading, `unused` readings are in
    no frame."""

    run: Run
    task: str
    fps: int
    t_s: np.ndarray
    """The run clock of each frame's hand reading (seconds, as recorded)."""
    state: np.ndarray
    action: np.ndarray
    tactile: np.ndarray | None = None
    images: dict[str, list[bytes]] = field(default_factory=dict)
    held: int = 0
    unused: int = 0

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def timestamp(self) -> np.ndarray:
        """Each frame's time from the episode's start as LeRobot's recorder writes it: index / fps."""
        return (np.arange(len(self), dtype=np.float64) / self.fps).astype(np.float32)


def held_index(sample_t: np.ndarray, at_t: np.ndarray) -> np.ndarray:
    """Index of the latest sample at or before each instant; -1 where there is none."""
    return np.searchsorted(sample_t, np.asarray(at_t) + _TIE_S, side="right") - 1


def _held(sample_t: np.ndarray, frame_t: np.ndarray) -> np.ndarray:
    """Index of the latest sample at or before each frame (the first sample before any)."""
    return np.clip(held_index(sample_t, frame_t), 0, len(sample_t) - 1)


def _answers(command_t: np.ndarray, frame_t: np.ndarray) -> np.ndarray:
    """Index of the command sent in answer to each frame's reading, else the one held before it."""
    first_after = np.searchsorted(command_t, frame_t - _TIE_S, side="left")
    next_t = np.append(frame_t[1:], np.inf)
    answered = first_after < len(command_t)
    answered[answered] &= command_t[first_after[answered]] < next_t[answered]
    return np.where(answered, first_after, np.clip(first_after - 1, 0, len(command_t) - 1))


def grid_readings(reading_t: np.ndarray, fps: int) -> np.ndarray:
    """For each frame k of the grid t0 + k / fps spanning the readings, the index of the latest reading
    taken by t0 + (k + 1/2) / fps (the nearest to the grid instant; the later one on a tie)."""
    t0 = reading_t[0]
    n = int(np.floor((reading_t[-1] - t0) * fps + 0.5 + _TIE_S)) + 1
    grid = t0 + (np.arange(n) + 0.5) / fps
    return np.clip(held_index(reading_t, grid), 0, len(reading_t) - 1)


def episode_frames(path: Path, images: bool = True) -> EpisodeFrames:
    """The frames of the run at `path` (a ConfigError, one line, if it has no hand or command stream)."""
    run = open_run(path)
    for stream in ("hand", "command"):
        if stream not in run.streams or not len(run.stream(stream)):
            raise ConfigError(f"{run.path}: no '{stream}' samples; an episode needs readings and commands")
    hand, command = run.stream("hand"), run.stream("command")
    fps = round(hand.spec.rate_hz)
    if fps < 1:
        raise ConfigError(f"{run.path}: the hand's rate {hand.spec.rate_hz:g} Hz rounds to no frame rate")
    answer = _answers(command.t_s, hand.t_s)  # per reading, before the readings are put on the grid
    at = grid_readings(hand.t_s, fps)
    t_s = hand.t_s[at]
    state = np.concatenate(
        [hand["position_counts"], hand["velocity_counts"], hand["strain_counts"]], axis=1
    ).astype(np.float32)[at]
    action = command["position_counts"][answer[at]].astype(np.float32)
    experiment = run.metadata.get("experiment") or {}
    name = experiment.get("name", "run") if isinstance(experiment, dict) else str(experiment)
    obj = experiment.get("object") if isinstance(experiment, dict) else None
    task = f"{name}: the Barrett BH8 hand squeezing {obj}" if obj and obj != "none" else f"{name}: BH8 hand"
    held = int(np.count_nonzero(at[1:] == at[:-1]))
    unused = len(hand) - len(np.unique(at))
    frames = EpisodeFrames(run, task, fps, t_s, state, action, held=held, unused=unused)
    if "tactile" in run.streams and len(run.stream("tactile")):
        tactile = run.stream("tactile")
        frames.tactile = tactile["counts"][_held(tactile.t_s, t_s)].astype(np.float32)
    if images and "stereo" in run.streams and len(run.stream("stereo")):
        stereo = run.stream("stereo")
        pair = _held(stereo.t_s, t_s)
        for side in ("left", "right"):
            jpegs = stereo[f"{side}_jpeg"]
            frames.images[side] = [bytes(np.asarray(jpegs[i], dtype=np.uint8)) for i in pair]
    return frames
