"""Compare two recorded runs of the same scenario (e.g. sim backend vs hardware backend).

Streams and units must match field by field; finger positions are compared after aligning the runs
in time (the hardware run starts when the port is ready, not at sim time zero). Works on recordings
only, so it runs unchanged on sim and hardware runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twin import units
from twin.interface.errors import ConfigError
from twin.recording import open_run
from twin.recording.reader import Run, StreamData


@dataclass(frozen=True)
class FieldMismatch:
    """A stream or field present in one run only, or with another unit or shape."""

    stream: str
    field: str
    a: str
    b: str


@dataclass(frozen=True)
class PositionAgreement:
    """Finger positions of run b against run a after shifting b by lag_s."""

    lag_s: float
    max_error_counts: np.ndarray
    """(3,) worst |b - a| per finger over the compared window (counts)."""
    rms_error_counts: np.ndarray
    """(3,) RMS error per finger (counts)."""
    travel_counts: np.ndarray
    """(3,) range of motion of each finger in run a (counts): the scale of the relative error."""

    @property
    def max_relative_error(self) -> float:
        """Worst error as a fraction of the finger's travel in run a."""
        return float(np.max(self.max_error_counts / np.maximum(self.travel_counts, 1.0)))


def stream_mismatches(
    run_a: Path | str, run_b: Path | str, streams: tuple[str, ...] = ("hand", "command", "tactile")
) -> list[FieldMismatch]:
    """Fields of `streams` whose presence, unit or shape differ between two runs (empty: the same)."""
    a, b = open_run(run_a), open_run(run_b)
    out = []
    for name in streams:
        fa = a.streams[name].fields if name in a.streams else {}
        fb = b.streams[name].fields if name in b.streams else {}
        for field in sorted(set(fa) | set(fb)):
            da = f"{fa[field].unit} {tuple(fa[field].shape)}" if field in fa else "missing"
            db = f"{fb[field].unit} {tuple(fb[field].shape)}" if field in fb else "missing"
            if da != db:
                out.append(FieldMismatch(name, field, da, db))
    return out


def position_agreement(
    run_a: Path | str,
    run_b: Path | str,
    *,
    max_lag_s: float = 0.5,
    lag_step_s: float = 0.002,
    margin_s: float = 0.5,
    exclude_s: tuple[tuple[float, float], ...] = (),
) -> PositionAgreement:
    """Align run b's finger positions to run a's (least squares over lags), then measure the errors.

    Both runs are compared on a's sample times, leaving `margin_s` at either end (where one run has
    no data after shifting) and the windows `exclude_s` (a's times) out.
    """
    a, b = _hand_positions(open_run(run_a)), _hand_positions(open_run(run_b))
    pa = a.fields["position_counts"][:, :3].astype(float)
    pb = b.fields["position_counts"][:, :3].astype(float)
    window = (a.t_s >= a.t_s[0] + margin_s) & (a.t_s <= a.t_s[-1] - margin_s)
    for t0, t1 in exclude_s:
        window &= ~((a.t_s >= t0) & (a.t_s <= t1))
    if not window.any():
        raise ConfigError(
            f"{run_a}: {a.t_s[-1] - a.t_s[0]:.2f} s of hand samples: too short to compare "
            f"(the comparison leaves {margin_s:g} s out at either end)"
        )
    best = None
    for lag in np.arange(-max_lag_s, max_lag_s + lag_step_s / 2, lag_step_s):
        shifted = np.stack([np.interp(a.t_s, b.t_s - lag, pb[:, k]) for k in range(3)], axis=1)
        err = (shifted - pa)[window]
        rms = float(np.sqrt(np.mean(err**2)))
        if best is None or rms < best[0]:
            best = (rms, lag, err)
    _, lag, err = best
    travel = pa.max(axis=0) - pa.min(axis=0)
    return PositionAgreement(
        lag_s=float(lag),
        max_error_counts=np.abs(err).max(axis=0),
        rms_error_counts=np.sqrt(np.mean(err**2, axis=0)),
        travel_counts=travel,
    )


def _hand_positions(run: Run) -> StreamData:
    """The run's hand stream, with finger positions and at least two samples (ConfigError otherwise)."""
    if "hand" not in run.streams or "position_counts" not in run.streams["hand"].fields:
        raise ConfigError(f"{run.path}: no hand positions recorded; nothing to compare")
    hand = run.stream("hand")
    if len(hand) < 2:
        raise ConfigError(f"{run.path}: {len(hand)} hand sample(s); a comparison needs at least two")
    return hand


def phase_changes_s(run: Path | str) -> list[float]:
    """Times at which the procedure changed phase (from the command stream; none without one)."""
    opened = open_run(run)
    if "command" not in opened.streams or "phase" not in opened.streams["command"].fields:
        return []
    command = opened.stream("command")
    phase = command.fields["phase"]
    return [float(command.t_s[i]) for i in np.flatnonzero(np.diff(phase) != 0) + 1]


def contact_windows_s(run: Path | str, half_width_s: float = 0.25) -> tuple[tuple[float, float], ...]:
    """The grasp, from the end of closing (first contact) to the start of compressing, widened by
    `half_width_s` either side: there contact events decide the path and their timing is a matter of
    a sample. One 33 ms sample of jitter at the 12000 counts/s approach is 400 counts by itself, and a
    finger the touch knocked off the object re-closes a sample sooner or later (experiments/compress.py).
    """
    changes = phase_changes_s(run)
    if not changes:
        return ()
    end = changes[1] if len(changes) > 1 else changes[0]
    return ((changes[0] - half_width_s, end + half_width_s),)


def describe(agreement: PositionAgreement) -> str:
    """One paragraph for the terminal."""
    full = units.FINGER_FULL_COUNTS
    rows = [
        f"F{k + 1}: max {agreement.max_error_counts[k]:.0f} counts, rms {agreement.rms_error_counts[k]:.0f}, "
        f"travel {agreement.travel_counts[k]:.0f}"
        for k in range(3)
    ]
    return (
        f"lag {agreement.lag_s * 1e3:+.0f} ms; "
        + "; ".join(rows)
        + f"; worst {agreement.max_relative_error:.2%} "
        f"of travel ({agreement.max_error_counts.max() / full:.2%} of the {full}-count range)"
    )
