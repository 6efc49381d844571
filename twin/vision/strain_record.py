"""The grasp's lateral and axial strains read back from a recorded compress run with two opposite pairs.

The run's two pairs that stand on opposite sides of the palm's x (their calibration's camera positions)
give the object's width at rest (the first frame) and at the squeeze's troughs (the balanced grasp,
every period from the start of the compress phase); the hand's recorded readings, replayed through
the kinematics, give the downward-facing taxels' height there: the object's top
(twin.vision.lateral_strain). What read_modulus_and_poisson needs, from the recording alone: the
same reader serves the run and the twin's simulations of it (twin.sim.poisson).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twin.interface.backend import stereo_calibration_key, stereo_stream_name
from twin.kinematics import ClutchObserver, HandKinematics
from twin.recording import Run
from twin.units import spread_counts_to_rad
from twin.vision import lateral_strain as ls
from twin.vision.calibration import StereoCalibration
from twin.vision.fusion import VISION

TROUGH_TOLERANCE = 0.05
"""How far (a fraction of the squeeze's period) a pair's frame may be from a trough it is read at: each
face there is within 1 - cos(2 pi 0.05) = 4.9 % of its excursion of the trough's (100 ms at the 0.5 Hz
squeeze), and the top is read at the +x pair's frame's instant, so their ratio moves less. A 30 fps pair's
nearest frame is within 17 ms, a 10 fps one's within 50 ms; a loaded 2-core host running four emulated
cameras delivered one 65 ms off."""
TROUGHS = 2
"""Troughs of the squeeze read (the balanced grasp recurs every period): the compress phase's start and
the next one, where the run lasts that long."""


@dataclass
class StrainObservation:
    """What two opposite pairs and the hand saw of one run: the object's width and top at rest and at
    the troughs, and where it stood (m, hand frame)."""

    width0_m: float
    height0_m: float
    palm_z_m: float
    """The palm's surface (hand frame z): the object's bottom."""
    width_m: list[float] = field(default_factory=list)
    top_m: list[float] = field(default_factory=list)
    face0_m: float = math.nan
    face_m: list[float] = field(default_factory=list)
    """The +x pair's own face (the one-pair statistic)."""
    centre_x_m: float = math.nan
    centre_y_reading_m: float = math.nan

    def ratio(self) -> float:
        """-eps_x/eps_z over the troughs seen (their mean)."""
        return float(
            np.mean(
                [
                    ls.strain_ratio(self.width0_m, w, self.height0_m, t - self.palm_z_m)
                    for w, t in zip(self.width_m, self.top_m, strict=True)
                ]
            )
        )

    def strains(self) -> tuple[float, float]:
        """(eps_x, eps_z) over the troughs seen (their mean): what read_modulus_and_poisson reads."""
        eps_x = np.mean([w / self.width0_m - 1.0 for w in self.width_m])
        eps_z = np.mean([(t - self.palm_z_m) / self.height0_m - 1.0 for t in self.top_m])
        return float(eps_x), float(eps_z)

    def one_face_ratio(self) -> float:
        """The +x face's outward shift over the axial strain (one pair)."""
        return float(
            np.mean(
                [
                    ls.strain_ratio(
                        self.width0_m,
                        self.width0_m + 2.0 * (f - self.face0_m),
                        self.height0_m,
                        t - self.palm_z_m,
                    )
                    for f, t in zip(self.face_m, self.top_m, strict=True)
                ]
            )
        )


def opposite_pair_streams(run: Run) -> tuple[str, str] | None:
    """The streams of the run's two pairs on opposite sides of the palm's x, (+x side, -x side): the
    pairs whose cameras stand furthest out on each side (their calibration's camera-to-hand pose); None
    where the run has no such two (one pair, or all on one side)."""
    names = run.metadata.get("stereo_placements") or []
    files = run.metadata.get("calibration_files") or {}
    side: dict[str, float] = {}
    for pair, name in enumerate(names):
        stream, key = stereo_stream_name(pair, name), stereo_calibration_key(pair, name)
        if stream in run.streams and key in files:
            side[stream] = float(StereoCalibration.load(Path(run.path) / files[key]).hand_from_left[0, 3])
    if len(side) < 2:
        return None
    plus, minus = max(side, key=side.get), min(side, key=side.get)
    return (plus, minus) if side[plus] > 0.0 > side[minus] else None


def _vision_points(run: Run, stream: str, k: int) -> NDArray[np.float64]:
    s = run.stream(stream)
    return np.asarray(s["points_m"][k][s["point_source"][k] == VISION], dtype=np.float64)


def _trough_times_s(run: Run, troughs: int) -> tuple[list[float], float]:
    """The squeeze's troughs within the run (the compress phase's first command, then every period), and
    the squeeze's period."""
    phases = run.metadata.get("phases") or []
    profile = (run.metadata.get("experiment") or {}).get("profile") or {}
    if "compress" not in phases or "frequency_hz" not in profile:
        raise ValueError("the run is not a compress run (no compress phase or squeeze frequency recorded)")
    command = run.stream("command")
    in_compress = np.flatnonzero(command["phase"] == phases.index("compress"))
    if not len(in_compress):
        raise ValueError("the grasp never reached the squeeze (no compress phase in the run)")
    start_s, period_s = float(command.t_s[in_compress[0]]), 1.0 / float(profile["frequency_hz"])
    end_s = float(command.t_s[-1])
    return [start_s + k * period_s for k in range(troughs) if start_s + k * period_s <= end_s], period_s


def _taxels_at(run: Run, times_s: list[float]) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """The taxels' hand-frame positions and normals at each time: the hand's readings replayed through
    the clutch observer and the kinematics (as the run's vision pipeline posed the hand)."""
    hand = run.stream("hand")
    clutch, kinematics = ClutchObserver(), HandKinematics()
    out, k = [], 0
    for t_s in sorted(times_s):
        while k < len(hand) and hand.t_s[k] <= t_s:
            links = clutch.update(hand["position_counts"][k], hand["strain_counts"][k])
            kinematics.set_angles(links, float(spread_counts_to_rad(hand["position_counts"][k][3])))
            k += 1
        out.append(kinematics.taxels())
    return out


Clouds = tuple[NDArray[np.float64], NDArray[np.float64]]
"""The vision points (hand frame) of the +x and the -x pair at one instant."""


def observation(
    rest: Clouds,
    troughs: Sequence[tuple[Clouds, NDArray[np.float64], NDArray[np.float64]]],
    height_m: float,
    palm_z_m: float,
) -> StrainObservation:
    """The strains from two opposite pairs' clouds at rest and, at each trough, their clouds and the
    taxels' hand-frame positions and normals. `height_m`: the object's rest height (its description);
    `palm_z_m`: the palm's surface (hand frame z). ValueError where a face is out of view."""
    plus, minus = rest
    seen = StrainObservation(ls.width_m(plus, minus, palm_z_m, height_m), height_m, palm_z_m)
    seen.face0_m = ls.face_position_m(plus, 1.0, palm_z_m, height_m)
    seen.centre_x_m = ls.centre_x_m(plus, minus, palm_z_m, height_m)
    seen.centre_y_reading_m = ls.centre_y_reading_m(plus, minus)
    for (plus, minus), taxels, normals in troughs:
        seen.width_m.append(ls.width_m(plus, minus, palm_z_m, height_m))
        seen.face_m.append(ls.face_position_m(plus, 1.0, palm_z_m, height_m))
        seen.top_m.append(ls.top_height_m(taxels, normals))
    return seen


def observe_run(run: Run, height_m: float, palm_z_m: float, troughs: int = TROUGHS) -> StrainObservation:
    """The strains of a recorded compress run seen by two opposite pairs (opposite_pair_streams): the
    first frame (rest) and the frames nearest the squeeze's troughs (observation). ValueError where the
    run cannot give them (one pair, no squeeze, a face out of view)."""
    streams = opposite_pair_streams(run)
    if streams is None:
        raise ValueError("the run has no two stereo pairs on opposite sides of the object")
    plus_name, minus_name = streams
    t_plus, t_minus = run.stream(plus_name).t_s, run.stream(minus_name).t_s
    if not len(t_plus) or not len(t_minus):
        raise ValueError(f"streams {plus_name} and {minus_name}: a pair recorded no frame")

    def clouds(k_plus: int, k_minus: int) -> Clouds:
        return _vision_points(run, plus_name, k_plus), _vision_points(run, minus_name, k_minus)

    # In the twin both pairs are sampled at the same instants; on hardware each pair's frames arrive on
    # their own (ms apart): at each trough, each pair's nearest frame, within TROUGH_TOLERANCE of it.
    trough_times_s, squeeze_period_s = _trough_times_s(run, troughs)
    tolerance_s = TROUGH_TOLERANCE * squeeze_period_s
    last_s = min(float(t_plus[-1]), float(t_minus[-1])) + tolerance_s  # a late loop's last commands
    trough_times_s = [t_s for t_s in trough_times_s if t_s <= last_s]  # may outlast its cameras' frames
    if not trough_times_s:
        raise ValueError(f"streams {plus_name} and {minus_name} end before the squeeze's first trough")
    at = []
    for t_s in trough_times_s:
        nearest = []
        for name, times in ((plus_name, t_plus), (minus_name, t_minus)):
            k = int(np.argmin(np.abs(times - t_s)))
            off_s = abs(float(times[k]) - t_s)
            if off_s > tolerance_s:
                raise ValueError(
                    f"stream {name} has no frame within {1e3 * tolerance_s:.0f} ms of the squeeze's trough "
                    f"at {t_s:.2f} s (the nearest: {1e3 * off_s:.0f} ms)"
                )
            nearest.append(k)
        at.append((nearest[0], nearest[1]))
    poses = _taxels_at(run, [float(t_plus[k_plus]) for k_plus, _ in at])  # the hand as the +x pair saw it
    at_troughs = [(clouds(*k), taxels, normals) for k, (taxels, normals) in zip(at, poses, strict=True)]
    rest = (0, 0)  # each pair's first frame: the object on the palm before the fingers reach it
    return observation(clouds(*rest), at_troughs, height_m, palm_z_m)
