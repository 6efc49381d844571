"""`twin identify`: eq. 4 on a recorded compress run, per finger, and the foam's modulus.

Steps (paper §3.1 and §6.2):
1. hand terms of eq. 4 from a free-motion run (twin.identify.hand_dynamics), or, without one, only the
   loaded run's own no-load gauge offset (documented degraded mode: no inertia, damping or gravity);
2. per finger: the contact onset (first fingertip reaction above CONTACT_FORCE_N, interpolated between
   samples), the indentation delta from there along the pad normal, its rate;
3. over whole compression cycles: the reaction model R(delta, delta_dot) fitted to the tactile R,
   the same R recovered from the strain gauges through eq. 4 (tau - hand terms over the measured
   moment arm) as a cross-check, and the secant stiffness mean R / mean delta;
4. the grip stiffness (summed gauge torques on summed drive counts) and the squeeze stiffness (the
   fingertips' secants summed), the statistic from which twin.sim.modulus infers E by running the
   run's procedure in the twin (`twin identify` joins the two; this module reads recordings only).
Samples where a finger sat at the safety layer's force cap are censored from steps 3 and 4
(uncapped_window): the cap, not the object, shaped them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twin.identify.hand_dynamics import TERMS, HandDynamics, derivatives, identify_hand
from twin.identify.reaction import IdentificationError, ReactionFit, fit_reaction
from twin.identify.signals import CONTACT_FORCE_N, FingerSignals, load_signals
from twin.recording import open_run
from twin.validation import check_run_metadata

WINDOW_SETTLE_S = 0.5
"""Compression samples skipped after the grasp settles (the balance servo's last transient)."""
DEFAULT_PERIOD_S = 2.0
"""Cycle length when the run does not record its compression frequency (compress default 0.5 Hz)."""
MAX_LOST_FRACTION = 0.1
"""A fingertip holding nothing in over 10 % of the compression has lost the object."""
MAX_CAPPED_FRACTION = 0.5
"""A compression with a finger at the force cap in over half its samples is refused: its uncapped
samples are the cycles' troughs only, where the squeeze is not excited."""
BASELINE_S = 0.3
"""Without a free-motion run, the gauge offset is the mean torque over the run's first 0.3 s (open hand)."""


@dataclass
class FingerResult:
    """One finger's identification and the series behind it (window samples only)."""

    finger: int
    fit: ReactionFit
    secant_n_m: float
    secant_sigma_n_m: float
    moment_arm_m: float
    eq4_residual_rms_nm: float
    onset_t_s: float
    cycles: int
    t_s: NDArray[np.float64]
    delta_m: NDArray[np.float64]
    rate_m_s: NDArray[np.float64]
    reaction_tactile_n: NDArray[np.float64]
    reaction_torque_n: NDArray[np.float64]
    reaction_model_n: NDArray[np.float64]

    def to_json(self) -> dict:
        """Plain-JSON form for the results file."""
        return {
            "finger": self.finger,
            "reaction_model": self.fit.to_json(),
            "secant_stiffness_n_m": self.secant_n_m,
            "secant_stiffness_sigma_n_m": self.secant_sigma_n_m,
            "moment_arm_mm": self.moment_arm_m * 1e3,
            "eq4_residual_rms_nm": self.eq4_residual_rms_nm,
            "torque_vs_tactile_rms_n": float(
                np.sqrt(np.mean((self.reaction_torque_n - self.reaction_tactile_n) ** 2))
            ),
            "contact_onset_t_s": self.onset_t_s,
            "cycles": self.cycles,
            "mean_indentation_mm": float(self.delta_m.mean() * 1e3),
            "mean_reaction_n": float(self.reaction_tactile_n.mean()),
        }


@dataclass
class Identification:
    """Everything `twin identify` reports."""

    run_path: Path
    model: str
    hand: HandDynamics
    fingers: list[FingerResult]
    notes: list[str] = field(default_factory=list)
    grip: tuple[float, float] = (float("nan"), float("nan"))
    """The grip's stiffness through the hand's own sensors and its 1-sigma (grip_stiffness)."""
    squeeze: tuple[float, float] = (float("nan"), float("nan"))
    """The squeeze stiffness (N/m) over the run's whole cycles and its 1-sigma (squeeze_stiffness)."""
    material: dict | None = None
    """The modulus and its interval (twin.sim.modulus.ModulusEstimate.to_json), where one was inferred."""
    censored: int = 0
    """Compression samples left out of every fit because a finger sat at the force cap (uncapped_window)."""

    def to_json(self) -> dict:
        """The results file's content."""
        return {
            "run": str(self.run_path),
            "model": self.model,
            "hand_terms": self.hand.to_json(),
            "fingers": [f.to_json() for f in self.fingers],
            "grip_stiffness_nm_per_kcount": self.grip[0],
            "grip_stiffness_sigma_nm_per_kcount": self.grip[1],
            "squeeze_stiffness_n_m": self.squeeze[0],
            "squeeze_stiffness_sigma_n_m": self.squeeze[1],
            "material": self.material,
            "censored_at_force_cap": self.censored,
            "notes": self.notes,
        }


def compression_window(
    signals: FingerSignals, max_cycles: int | None = None
) -> tuple[NDArray[np.bool_], int]:
    """Samples of whole compression cycles after the grasp settled (the first `max_cycles` of them, if
    given), and how many cycles."""
    compress = signals.phase_mask("compress")
    if not compress.any():
        raise IdentificationError(
            f"{signals.run_path}: no 'compress' phase recorded "
            "(identification needs a `twin run compress` run)"
        )
    t0 = signals.t_s[compress][0] + WINDOW_SETTLE_S
    t_end = signals.t_s[compress][-1]
    profile = signals.metadata.get("experiment", {}).get("profile", {})
    period = 1.0 / profile["frequency_hz"] if profile.get("frequency_hz") else DEFAULT_PERIOD_S
    cycles = int((t_end - t0) // period)
    if max_cycles is not None:
        cycles = min(cycles, max_cycles)
    if cycles < 1:
        raise IdentificationError(
            f"{signals.run_path}: {t_end - t0:.1f} s of compression; identification needs one whole cycle "
            f"({period:.1f} s) after the grasp settles (record a longer run)"
        )
    window = compress & (signals.t_s >= t0) & (signals.t_s < t0 + cycles * period)
    return window, cycles


def capped(signals: FingerSignals) -> NDArray[np.bool_]:
    """(n, 3) samples where a finger sat at the force cap (none where the run cannot say)."""
    if signals.at_cap is None:
        return np.zeros((len(signals.t_s), 3), dtype=bool)
    return signals.at_cap


def uncapped_window(
    signals: FingerSignals, max_cycles: int | None = None
) -> tuple[NDArray[np.bool_], int, int]:
    """The compression window (compression_window) less its samples with any finger at the force cap
    (censored: the safety layer, not the object, shaped them), the cycles, and how many were censored.
    IdentificationError, one line, where over MAX_CAPPED_FRACTION of the window was at the cap."""
    window, cycles = compression_window(signals, max_cycles)
    at_cap = capped(signals).any(axis=1) & window
    censored = int(at_cap.sum())
    if censored > MAX_CAPPED_FRACTION * window.sum():
        which = np.flatnonzero((capped(signals) & window[:, None]).any(axis=0))
        fingers = ", ".join(f"F{k + 1}" for k in which)
        raise IdentificationError(
            f"{signals.run_path}: a finger sat at the fingertip-force cap ({fingers}) in {censored} of "
            f"{int(window.sum())} compression samples: too few uncapped samples to read the object from "
            "(record it again with a smaller squeeze)"
        )
    return window & ~at_cap, cycles, censored


def grip_stiffness(signals: FingerSignals, window: NDArray[np.bool_], cycles: int) -> tuple[float, float]:
    """The whole grip's stiffness as the hand's own sensors see it: the slope of the summed distal
    torques (strain gauges, eq. 2) against the summed drive counts over whole cycles, in N*m per 1000
    counts, with a 1-sigma from the spread of the cycles' own slopes.

    It does not care which link or pad of a finger carries the load, which is what varies from run to
    run on soft foams (a thumb pushing with its inner link or its fingertip), so it stays steady where
    the fingertip pads' stiffnesses do not (docs/identification.md)."""
    drive = signals.drive_counts.sum(axis=1) / 1e3
    torque = signals.torque_nm.sum(axis=1)

    def slope(idx: NDArray[np.int64]) -> float:
        d = drive[idx] - drive[idx].mean()
        return float(d @ (torque[idx] - torque[idx].mean()) / (d @ d)) if d @ d > 0 else float("nan")

    per_cycle = np.array([slope(i) for i in _cycles(window, cycles)])
    n = len(per_cycle)
    sigma = float(per_cycle.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
    return slope(np.flatnonzero(window)), sigma


def _cycles(window: NDArray[np.bool_], cycles: int) -> list[NDArray[np.int64]]:
    """The window's sample indices, cycle by cycle (a censored window: split over its whole span; a
    cycle with fewer than 3 uncensored samples has no slope of its own and is left out)."""
    first, last = np.flatnonzero(window)[[0, -1]]
    span = np.arange(first, last + 1)
    return [kept for i in np.array_split(span, cycles) if len(kept := i[window[i]]) >= 3]


def contact_reference(signals: FingerSignals, finger: int) -> tuple[float, NDArray, NDArray]:
    """Onset time, fingertip pad centre and normal at first contact, interpolated between samples."""
    r = signals.reaction_n[:, finger]
    over = np.flatnonzero(r > CONTACT_FORCE_N)
    if not over.size:
        raise IdentificationError(
            f"{signals.run_path}: F{finger + 1}'s fingertip pad never read more than "
            f"{CONTACT_FORCE_N} N: no contact"
        )
    i = int(over[0])
    if i == 0:
        return float(signals.t_s[0]), signals.tip_position_m[0, finger], signals.tip_normal[0, finger]
    f = (CONTACT_FORCE_N - r[i - 1]) / (r[i] - r[i - 1])
    p = signals.tip_position_m[i - 1, finger] + f * (
        signals.tip_position_m[i, finger] - signals.tip_position_m[i - 1, finger]
    )
    t = signals.t_s[i - 1] + f * (signals.t_s[i] - signals.t_s[i - 1])
    return float(t), p, signals.tip_normal[i - 1, finger]


def _baseline_hand(signals: FingerSignals) -> HandDynamics:
    early = signals.t_s < signals.t_s[0] + BASELINE_S
    offset = signals.torque_nm[early].mean(axis=0)
    params = [dict.fromkeys(TERMS, 0.0) | {"offset_nm": float(offset[k])} for k in range(3)]
    sigma = [dict.fromkeys(TERMS, float("nan")) for _ in range(3)]
    return HandDynamics(
        params=params, sigma=sigma, rms_nm=[float("nan")] * 3, source="no-load offset of the run"
    )


def identify_run(
    run: Path | str,
    free_run: Path | str | None = None,
    model: str = "kelvin-voigt",
) -> Identification:
    """Identify eq. 4 per finger from a compress run (and optionally a free-motion run); the modulus is
    twin.sim.modulus's, which runs the procedure in the twin."""
    for path in (run, free_run) if free_run is not None else (run,):  # metadata types: one line if not
        check_run_metadata(open_run(path).info, Path(path) / "run.json")
    signals = load_signals(run)
    notes: list[str] = []
    if free_run is not None:
        hand = identify_hand(load_signals(free_run, need_tactile=False))
    else:
        hand = _baseline_hand(signals)
        notes.append(
            "no free-motion run (--free): eq. 4's hand terms are only the gauge's no-load offset; "
            "inertia, damping and gravity are left out of the torque cross-check"
        )
    window, cycles, censored = uncapped_window(signals)
    if censored:
        per_finger = (capped(signals) & compression_window(signals)[0][:, None]).sum(axis=0)
        notes.append(
            f"{censored} compression samples had a finger at the fingertip-force cap "
            f"({', '.join(f'F{k + 1}: {n}' for k, n in enumerate(per_finger) if n)}): censored, "
            "left out of every fit (the safety layer, not the object, shaped them)"
        )
    hand_torque = hand.torque_nm(signals)
    fingers = []
    for k in range(3):
        onset_t, p0, n0 = contact_reference(signals, k)
        delta = (signals.tip_position_m[:, k] - p0) @ n0
        rate, _ = derivatives(signals.t_s, delta[:, None])
        rate = rate[:, 0]
        r_tac = signals.reaction_n[window, k]
        fit = fit_reaction(model, delta[window], rate[window], r_tac)
        moment = signals.reaction_torque_nm[window, k]
        arm = float(moment.sum() / r_tac.sum()) if r_tac.sum() > 0 else float("nan")
        tau_ext = signals.torque_nm[window, k] - hand_torque[window, k]
        per_cycle = _cycles(window, cycles)
        secants = np.array([signals.reaction_n[i, k].mean() / delta[i].mean() for i in per_cycle])
        secant = float(r_tac.mean() / delta[window].mean())
        n = len(secants)
        sigma = float(secants.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
        fingers.append(
            FingerResult(
                finger=k + 1,
                fit=fit,
                secant_n_m=secant,
                secant_sigma_n_m=sigma,
                moment_arm_m=arm,
                eq4_residual_rms_nm=float(np.sqrt(np.mean((tau_ext - moment) ** 2))),
                onset_t_s=onset_t,
                cycles=cycles,
                t_s=signals.t_s[window],
                delta_m=delta[window],
                rate_m_s=rate[window],
                reaction_tactile_n=r_tac,
                reaction_torque_n=tau_ext / arm,
                reaction_model_n=fit.predict(delta[window], rate[window]),
            )
        )
    grip = grip_stiffness(signals, window, cycles)
    squeeze = squeeze_stiffness(signals)
    return Identification(signals.run_path, model, hand, fingers, notes, grip, squeeze[:2], censored=censored)


def squeeze_stiffness(signals: FingerSignals, max_cycles: int | None = None) -> tuple[float, float, int]:
    """The grasp's squeeze stiffness (N/m): the slope of the fingertips' summed reaction (tactile R,
    eq. 6) against their summed travel into the object (each along its pad normal) over whole
    cycles; its 1-sigma from the spread of the cycles' own slopes; the cycles used.

    A slope needs no contact point: a secant R / delta does, and first contact falls between two
    30 Hz samples (4 mm of fingertip travel at the close's speed), which moved single secants by 40 %.
    Sums, because the object shifts between the fingers as they squeeze: one fingertip may even back
    off while the others push, but the squeeze is the total (docs/identification.md). Fingertips that
    never touch the object in the window are left out, and so are samples with a finger at the force
    cap (censored, uncapped_window). IdentificationError when the pads held nothing in over
    MAX_LOST_FRACTION of the compression (the object slipped out of the grasp) or a finger sat at the
    cap in over MAX_CAPPED_FRACTION of it."""
    if signals.reaction_n is None:
        raise IdentificationError(f"{signals.run_path}: no tactile reaction; the squeeze stiffness needs it")
    full, _ = compression_window(signals, max_cycles)
    lost = float(np.mean(signals.reaction_n[full].sum(axis=1) < CONTACT_FORCE_N))
    if lost > MAX_LOST_FRACTION:
        raise IdentificationError(
            f"{signals.run_path}: the fingertips held nothing (under {CONTACT_FORCE_N} N together) in "
            f"{100 * lost:.0f} % of the compression: the object slipped out of the grasp or was never held, "
            "so its stiffness cannot be read"
        )
    window, cycles, _ = uncapped_window(signals, max_cycles)
    reaction = signals.reaction_n[window]
    first = int(np.flatnonzero(window)[0])
    touching = (reaction > CONTACT_FORCE_N).any(axis=0)
    travel = np.column_stack(
        [
            (signals.tip_position_m[:, k] - signals.tip_position_m[first, k]) @ signals.tip_normal[first, k]
            for k in range(3)
        ]
    )[:, touching].sum(axis=1)
    force = signals.reaction_n[:, touching].sum(axis=1)

    def slope(idx: NDArray[np.int64]) -> float:
        d = travel[idx] - travel[idx].mean()
        return float(d @ (force[idx] - force[idx].mean()) / (d @ d)) if d @ d > 0 else float("nan")

    total = slope(np.flatnonzero(window))
    if not total > 0:
        raise IdentificationError(
            f"{signals.run_path}: the fingertips' force did not rise as they pressed into the object "
            "through the compression: no squeeze stiffness"
        )
    per_cycle = np.array([slope(i) for i in _cycles(window, cycles)])
    n = len(per_cycle)
    sigma = float(per_cycle.std(ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
    return total, sigma, cycles


def fingertip_contact(signals: FingerSignals, max_cycles: int | None = None) -> NDArray[np.float64]:
    """(3,) the fraction of the compared compression (its uncapped samples) in which each fingertip pad
    touched the object: which fingers hold it with their tips is the grasp's configuration, and a twin
    that grasps the object otherwise is not measuring the same stiffness."""
    window, _, _ = uncapped_window(signals, max_cycles)
    return np.mean(signals.reaction_n[window] > CONTACT_FORCE_N, axis=0)


def fingertip_shares(signals: FingerSignals, max_cycles: int | None = None) -> NDArray[np.float64]:
    """(3,) each fingertip's share of the fingertips' summed mean reaction over the compared
    compression: how the grasp spreads the squeeze over the fingers. It moves with the object's
    placement and jumps where the grasp settles otherwise (a finger that barely holds), and S with it;
    the modulus compares only like grasps (twin.sim.modulus)."""
    window, _, _ = uncapped_window(signals, max_cycles)
    mean = signals.reaction_n[window].mean(axis=0)
    return mean / mean.sum() if mean.sum() > 0 else np.full(3, math.nan)
