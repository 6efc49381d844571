"""Hardware units <-> physical units, shared by the sim and hardware backends.

Every constant of the BH8's internal sensors lives here once, next to its source
(paper = ../shared/reference/paper.md, eqs. 1-3; bh262.h = mmmatjaz/BarrettHand). The sim
produces readings through the inverse of these maps, so both backends go through one module.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

# --- Encoders (paper §3.1) -------------------------------------------------------------------
FINGER_FULL_COUNTS = 17_000
"""Finger motor counts from fully open to fully closed (paper §3.1; bh262.h uses 17,500)."""
FINGER_FULL_INNER_RAD = math.radians(140.0)
"""Inner-link travel over FINGER_FULL_COUNTS (paper §3.1, jhu-lcsr URDF joint limit)."""
FINGER_MAX_COUNTS = 17_800
"""Largest finger position the firmware accepts (BH8-262 manual, bh262_protocol.md §Ranges)."""
SPREAD_FULL_COUNTS = 3_140
"""Spread counts from 0 to 180 degrees (paper §3.1; bh262.h uses 3,150)."""
SPREAD_FULL_RAD = math.pi

INNER_RAD_PER_COUNT = FINGER_FULL_INNER_RAD / FINGER_FULL_COUNTS
"""Inner-link angle per finger-motor count (gear ratio 125:1 folded in)."""
OUTER_RATIO_COUPLED = 1.0 / 3.0
"""Outer/inner angle ratio before breakaway: gear ratios 375:1 vs 125:1 (libbarrett hand.h)."""
OUTER_RATIO_BROKEN_AWAY = 4.0 / 3.0
"""Outer-link angle per inner-equivalent drive angle after breakaway: 4/375 vs 1/125 (paper §3.1)."""
SPREAD_RAD_PER_COUNT = SPREAD_FULL_RAD / SPREAD_FULL_COUNTS

# --- Velocity (paper eq. 1) ------------------------------------------------------------------
VELOCITY_SAMPLE_TIME_S = 0.010
"""Time base of a velocity reading: Barrett's BHand API reports encoder ticks per 10 ms.

The paper quotes Ts = 256 us and eq. 1; taken literally eq. 1 disagrees with the position scale by
four orders of magnitude (see models/barrett_mjcf/README.md), so velocity is converted with the same
counts-to-angle scale as position. 256 us remains selectable in the hand config.
"""
PAPER_SAMPLE_TIME_S = 256e-6
"""Ts of the hand electronics as printed in paper §3.1."""

# --- Strain gauges (paper eqs. 2 and 3) ------------------------------------------------------
SG_TORQUE_OFFSET_NM = -1.1675
SG_TORQUE_SLOPE_NM = 0.0085
"""Eq. 2: T = -1.1675 + 0.0085 * SG, distal-joint torque in N*m. The sim follows eq. 2."""
SG_FORCE_OFFSET_KG = -2.2118
SG_FORCE_SLOPE_KG = 0.0167
"""Eq. 3: F = -2.2118 + 0.0167 * SG, fingertip force in kg. At eq. 2's zero (SG 137.35) it reads
0.082 kg: the two fits disagree at zero load, see models/barrett_mjcf/README.md."""
SG_MIN, SG_MAX = 0, 255
"""Strain gauge range; 255 also means 'no gauge fitted' on the 262 (bh262_protocol.md)."""
FINGERTIP_FORCE_LIMIT_KG = 2.0
"""Largest fingertip force the hand accommodates (paper §3.1)."""
FINGERTIP_MOMENT_ARM_M = 0.050
"""Distal-joint to fingertip moment arm (paper §3.1, eq. 4 discussion)."""
GRAVITY_M_S2 = 9.81


def _as_float(x: ArrayLike) -> NDArray[np.float64]:
    return np.asarray(x, dtype=np.float64)


def finger_counts_to_inner_rad(counts: ArrayLike) -> NDArray[np.float64]:
    """Finger motor counts -> inner-link angle (rad), valid while the clutch is coupled."""
    return _as_float(counts) * INNER_RAD_PER_COUNT


def inner_rad_to_finger_counts(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Inner-equivalent drive angle (rad) -> finger motor counts (not rounded)."""
    return _as_float(angle_rad) / INNER_RAD_PER_COUNT


def spread_counts_to_rad(counts: ArrayLike) -> NDArray[np.float64]:
    """Spread motor counts -> spread angle of F1 and F2 (rad)."""
    return _as_float(counts) * SPREAD_RAD_PER_COUNT


def spread_rad_to_counts(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Spread angle (rad) -> spread motor counts (not rounded)."""
    return _as_float(angle_rad) / SPREAD_RAD_PER_COUNT


def velocity_counts_to_rad_s(
    counts_per_sample: ArrayLike, sample_time_s: float = VELOCITY_SAMPLE_TIME_S
) -> NDArray[np.float64]:
    """Finger velocity reading (counts per sample time) -> inner-equivalent drive rate (rad/s)."""
    return _as_float(counts_per_sample) / sample_time_s * INNER_RAD_PER_COUNT


def drive_rad_s_to_velocity_counts(
    rate_rad_s: ArrayLike, sample_time_s: float = VELOCITY_SAMPLE_TIME_S
) -> NDArray[np.float64]:
    """Inner-equivalent drive rate (rad/s) -> counts per sample time (not rounded)."""
    return _as_float(rate_rad_s) * sample_time_s / INNER_RAD_PER_COUNT


def strain_to_torque_nm(strain_counts: ArrayLike) -> NDArray[np.float64]:
    """Paper eq. 2: strain gauge reading (0-255) -> distal-joint torque (N*m)."""
    return SG_TORQUE_OFFSET_NM + SG_TORQUE_SLOPE_NM * _as_float(strain_counts)


def torque_nm_to_strain(torque_nm: ArrayLike) -> NDArray[np.float64]:
    """Inverse of eq. 2, not rounded or clipped (the device model quantizes and saturates)."""
    return (_as_float(torque_nm) - SG_TORQUE_OFFSET_NM) / SG_TORQUE_SLOPE_NM


def strain_to_force_kg(strain_counts: ArrayLike) -> NDArray[np.float64]:
    """Paper eq. 3: strain gauge reading (0-255) -> fingertip force (kg)."""
    return SG_FORCE_OFFSET_KG + SG_FORCE_SLOPE_KG * _as_float(strain_counts)


def force_kg_to_strain(force_kg: ArrayLike) -> NDArray[np.float64]:
    """Inverse of eq. 3, not rounded or clipped."""
    return (_as_float(force_kg) - SG_FORCE_OFFSET_KG) / SG_FORCE_SLOPE_KG


NO_LOAD_STRAIN = float(torque_nm_to_strain(0.0))
"""Strain reading at zero torque under eq. 2 (137.35): what the sim's unloaded gauge reads."""


def hand_reading_to_physical(
    position_counts: ArrayLike,
    velocity_counts: ArrayLike,
    strain_counts: ArrayLike,
    velocity_sample_time_s: float = VELOCITY_SAMPLE_TIME_S,
) -> dict[str, NDArray[np.float64]]:
    """Physical view of hand readings (motors F1, F2, F3, S), same for every backend.

    Returns drive angles (rad: fingers as inner-equivalent angle, spread angle), their rates (rad/s),
    distal-joint torque (eq. 2, N*m) and fingertip force (eq. 3, kg).
    """
    pos = _as_float(position_counts)
    vel = _as_float(velocity_counts)
    scale = np.array([INNER_RAD_PER_COUNT] * 3 + [SPREAD_RAD_PER_COUNT])
    return {
        "position_rad": pos * scale,
        "velocity_rad_s": vel / velocity_sample_time_s * scale,
        "torque_nm": strain_to_torque_nm(strain_counts),
        "force_kg": strain_to_force_kg(strain_counts),
    }
