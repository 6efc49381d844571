"""A recorded run turned into the signals of eq. 4, per finger, on the hand's 30 Hz clock.

Only recorded readings are used (encoder counts, strain-gauge torques, tactile pressures), so a
hardware run goes through exactly the same code as a sim run. Link angles come from the counts
through the clutch observer (twin.kinematics); the fingertip pad's centre and normal from the hand's
forward kinematics; the reaction force R is the fingertip pad's lumped force (eq. 6) and its moment
about the distal joint is the pressure-weighted taxel lever (J^T R of eq. 4, measured, not assumed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twin import units
from twin.kinematics import ClutchObserver, HandKinematics
from twin.recording.reader import Run, RunFormatError
from twin.tactile.calibration import active
from twin.tactile.layout import FINGERTIP_PADS, LAYOUT

FINGERS = (1, 2, 3)
CONTACT_FORCE_N = 0.3
"""A fingertip pad reading above this lumped force (eq. 6) is in contact with the object."""


class MissingStreamError(RunFormatError):
    """The run lacks a stream or field identification needs; the message names it."""


@dataclass
class FingerSignals:
    """Per-sample signals of the three fingers; arrays are (n, 3) unless noted."""

    run_path: Path
    t_s: NDArray[np.float64]
    """(n,) hand sample times (s)."""
    drive_counts: NDArray[np.float64]
    torque_nm: NDArray[np.float64]
    """Distal-joint torque from the strain gauges (eq. 2)."""
    outer_rad: NDArray[np.float64]
    """Distal (outer-link) joint angle from the counts, through the clutch observer."""
    link_abs_rad: NDArray[np.float64]
    """Outer link's absolute angle (inner + outer) in its finger plane, for the gravity term."""
    tip_position_m: NDArray[np.float64]
    """(n, 3, 3) fingertip pad centre in the hand frame."""
    tip_normal: NDArray[np.float64]
    """(n, 3, 3) fingertip pad outward normal in the hand frame."""
    at_cap: NDArray[np.bool_] | None = None
    """(n, 3) where each finger's fingertip force (eq. 3, from its gauge) sat at the safety layer's cap:
    there the layer stopped it closing, so its curves are the cap's, not the object's (censored)."""
    phase: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(n,) index into `phases`; -1 where unknown."""
    phases: tuple[str, ...] = ()
    reaction_n: NDArray[np.float64] | None = None
    """Fingertip pad lumped force (eq. 6), resampled to the hand clock; None without tactile."""
    reaction_torque_nm: NDArray[np.float64] | None = None
    """Moment of the fingertip pad pressures about the distal joint (sum of P_i A_i x_i)."""
    metadata: dict = field(default_factory=dict)

    @property
    def dt_s(self) -> float:
        """Median sample interval (s)."""
        return float(np.median(np.diff(self.t_s))) if len(self.t_s) > 1 else float("nan")

    def phase_mask(self, name: str) -> NDArray[np.bool_]:
        """(n,) samples recorded in the named phase (all False if the run has no such phase)."""
        if name not in self.phases:
            return np.zeros(len(self.t_s), dtype=bool)
        return self.phase == self.phases.index(name)

    def indentation_m(self, reference: int | NDArray[np.int64]) -> NDArray[np.float64]:
        """(n, 3) fingertip travel into the object along its pad normal, from sample `reference`
        (one index for every finger, or one per finger)."""
        ref = np.broadcast_to(np.asarray(reference), (3,))
        out = np.empty((len(self.t_s), 3))
        for k in range(3):
            p0, n0 = self.tip_position_m[ref[k], k], self.tip_normal[ref[k], k]
            out[:, k] = (self.tip_position_m[:, k] - p0) @ n0
        return out


def _require(run: Run, stream: str, fields: tuple[str, ...], why: str) -> None:
    if stream not in run.streams:
        raise MissingStreamError(f"{run.path}: no '{stream}' stream, which {why} needs")
    missing = [f for f in fields if f not in run.streams[stream].fields]
    if missing:
        raise MissingStreamError(
            f"{run.path}: stream '{stream}' lacks {', '.join(missing)}, which {why} needs"
        )


def load_signals(path: Path | str, *, need_tactile: bool = True) -> FingerSignals:
    """Read a run and derive the per-finger signals; MissingStreamError names what is missing."""
    run = Run(path)
    _require(run, "hand", ("position_counts", "strain_counts"), "identification")
    hand = run.stream("hand")
    if len(hand) < 30:
        raise MissingStreamError(
            f"{run.path}: only {len(hand)} hand samples; identification needs >= 30 (1 s)"
        )
    if need_tactile:
        _require(run, "tactile", ("pressure_kpa",), "the reaction force R (eq. 6)")
    t = hand.t_s.astype(float)
    counts = hand["position_counts"].astype(float)
    strain = hand["strain_counts"].astype(float)
    torque = units.strain_to_torque_nm(strain)

    observer = ClutchObserver()
    kin = HandKinematics()
    tip_ids = [np.flatnonzero(LAYOUT.pad_index == LAYOUT.pad_names.index(p)) for p in FINGERTIP_PADS]
    n = len(t)
    outer = np.empty((n, 3))
    inner = np.empty((n, 3))
    tip_p = np.empty((n, 3, 3))
    tip_n = np.empty((n, 3, 3))
    spread = units.spread_counts_to_rad(counts[:, 3])
    for i in range(n):
        links = observer.update(counts[i], strain[i])
        inner[i], outer[i] = links[:, 0], links[:, 1]
        kin.set_angles(links, float(spread[i]))
        pos, nrm = kin.taxels()
        for k, ids in enumerate(tip_ids):
            tip_p[i, k] = pos[ids].mean(axis=0)
            tip_n[i, k] = nrm[ids].mean(axis=0)
    tip_n /= np.linalg.norm(tip_n, axis=2, keepdims=True)

    phases: tuple[str, ...] = tuple(run.metadata.get("phases", ()))
    phase = np.full(n, -1, dtype=np.int64)
    if "command" in run.streams and "phase" in run.streams["command"].fields:
        cmd = run.stream("command")
        if len(cmd):
            idx = np.clip(np.searchsorted(cmd.t_s, t, side="right") - 1, 0, len(cmd) - 1)
            phase = cmd["phase"].astype(np.int64)[idx]

    cap = run.metadata.get("force_cap")
    limit_kg = cap.get("limit_kg") if isinstance(cap, dict) else None
    if not isinstance(limit_kg, int | float) or isinstance(limit_kg, bool) or not limit_kg > 0:
        limit_kg = units.FINGERTIP_FORCE_LIMIT_KG  # runs recorded before the cap was kept in run.json
    signals = FingerSignals(
        run_path=run.path,
        t_s=t,
        drive_counts=counts[:, :3],
        torque_nm=torque,
        at_cap=units.strain_to_force_kg(strain[:, :3]) >= limit_kg,
        outer_rad=outer,
        link_abs_rad=inner + outer,
        tip_position_m=tip_p,
        tip_normal=tip_n,
        phase=phase,
        phases=phases,
        metadata=run.metadata,
    )
    if "tactile" in run.streams and "pressure_kpa" in run.streams["tactile"].fields:
        tac = run.stream("tactile")
        if len(tac) >= 2:
            signals.reaction_n, signals.reaction_torque_nm = _fingertip_reaction(
                tac.t_s, tac["pressure_kpa"], t
            )
    if need_tactile and signals.reaction_n is None:
        raise MissingStreamError(f"{run.path}: the 'tactile' stream is empty; the reaction force R needs it")
    return signals


def _fingertip_reaction(
    t_tactile: NDArray[np.float64], pressure_kpa: NDArray[np.float64], t_hand: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Eq. 6 per fingertip pad (sum of P_i A_i) and its moment about the distal joint (sum of P_i A_i x_i),
    linearly resampled onto the hand clock."""
    p = np.asarray(pressure_kpa, dtype=float)
    force_per_taxel = np.where(active(p), p * 1e3 * LAYOUT.area_m2, 0.0)  # eq. 6's active taxels, N
    lever = LAYOUT.position_m[:, 0]  # along the outer link from the distal joint (layout.py)
    force = np.empty((len(t_hand), 3))
    moment = np.empty((len(t_hand), 3))
    for k, pad in enumerate(FINGERTIP_PADS):
        ids = LAYOUT.pad_index == LAYOUT.pad_names.index(pad)
        f = force_per_taxel[:, ids].sum(axis=1)
        m = (force_per_taxel[:, ids] * lever[ids]).sum(axis=1)
        force[:, k] = np.interp(t_hand, t_tactile, f)
        moment[:, k] = np.interp(t_hand, t_tactile, m)
    return force, moment
