"""One run as frames at the hand's rate: what a LeRobot episode holds.

Every hand reading is a frame. Beside it: the command the rig sent in answer to it (the first command
recorded at or after the reading and before the next one; where there is none the previous command is
held), and the latest tactile scan and stereo pair at or before the reading (zero-order hold), so no
frame sees a sample from its future.
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


@dataclass
class EpisodeFrames:
    """A run's frames: times, state, action, and where recorded tactile counts and JPEG pairs."""

    run: Run
    task: str
    fps: int
    t_s: np.ndarray
    state: np.ndarray
    action: np.ndarray
    tactile: np.ndarray | None = None
    images: dict[str, list[bytes]] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_s)


def _held(sample_t: np.ndarray, frame_t: np.ndarray) -> np.ndarray:
    """Index of the latest sample at or before each frame (the first sample before any)."""
    return np.clip(np.searchsorted(sample_t, frame_t + 1e-9, side="right") - 1, 0, len(sample_t) - 1)


def _answers(command_t: np.ndarray, frame_t: np.ndarray) -> np.ndarray:
    """Index of the command sent in answer to each frame's reading, else the one held before it."""
    first_after = np.searchsorted(command_t, frame_t - 1e-9, side="left")
    next_t = np.append(frame_t[1:], np.inf)
    answered = first_after < len(command_t)
    answered[answered] &= command_t[first_after[answered]] < next_t[answered]
    return np.where(answered, first_after, np.clip(first_after - 1, 0, len(command_t) - 1))


def episode_frames(path: Path, images: bool = True) -> EpisodeFrames:
    """The frames of the run at `path` (a ConfigError, one line, if it has no hand or command stream)."""
    run = open_run(path)
    for stream in ("hand", "command"):
        if stream not in run.streams or not len(run.stream(stream)):
            raise ConfigError(f"{run.path}: no '{stream}' samples; an episode needs readings and commands")
    hand, command = run.stream("hand"), run.stream("command")
    t_s = hand.t_s
    state = np.concatenate(
        [hand["position_counts"], hand["velocity_counts"], hand["strain_counts"]], axis=1
    ).astype(np.float32)
    action = command["position_counts"][_answers(command.t_s, t_s)].astype(np.float32)
    experiment = run.metadata.get("experiment") or {}
    name = experiment.get("name", "run") if isinstance(experiment, dict) else str(experiment)
    obj = experiment.get("object") if isinstance(experiment, dict) else None
    task = f"{name}: the Barrett BH8 hand squeezing {obj}" if obj and obj != "none" else f"{name}: BH8 hand"
    frames = EpisodeFrames(run, task, round(hand.spec.rate_hz), t_s, state, action)
    if "tactile" in run.streams and len(run.stream("tactile")):
        tactile = run.stream("tactile")
        frames.tactile = tactile["counts"][_held(tactile.t_s, t_s)].astype(np.float32)
    if images and "stereo" in run.streams and len(run.stream("stereo")):
        stereo = run.stream("stereo")
        at = _held(stereo.t_s, t_s)
        for side in ("left", "right"):
            jpegs = stereo[f"{side}_jpeg"]
            frames.images[side] = [bytes(np.asarray(jpegs[i], dtype=np.uint8)) for i in at]
    return frames
