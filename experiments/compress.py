"""The paper's identification procedure (§6.2): grasp, balance the grasp forces, then compress.

Backend-agnostic: it sees only hand readings (counts, strain) and sends position set points, so the
same code drives the twin and the real hand. The compression follows the eq. 7 family
m_k(t) = p_k + s (offset + amplitude * sin(omega * t + phase)), in encoder counts, where p_k is
finger k's balanced grasp position. The paper's printed constants (10 + 40 sin(3000 t) at 18
samples/s) alias, so the defaults below are chosen to compress the foam a few millimetres at a rate
the 30 Hz loop resolves (60 samples per period).

The squeeze stays inside the hand's envelope (`envelope`): s in [0, 1] scales the wave, the same on
every finger as in eq. 7, so that no finger's distal torque comes within `cap_margin` of the torque at
which eq. 3 reads the 2 kg fingertip cap, where the safety layer would stop the finger closing and
notch the curves. s is chosen when the compression starts, from the stiffness each finger showed in
the balance (peak torque = grasp torque + stiffness x peak travel), and cut during the compression
where a finger's torque still reaches that ceiling: the balance's stiffness is read while fingers
open and close about their grasp, sometimes in another clutch state, and a finger may meet something
stiffer than the object on the way (the thumb's distal link reaches its joint stop on the default
block; docs/identification.md). After a cut the wave takes that finger only as far as it had
travelled at its last reading under the ceiling. One scale for the hand, not one per finger: scaling
only the finger at the ceiling moved its share of the squeeze with the object's placement, which the
modulus compares (docs/identification.md). run.json's `squeeze_amplitude` states the amplitude and
why.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from twin import units
from twin.interface.devices import HandCommand, HandReading
from twin.interface.errors import ConfigError

if TYPE_CHECKING:
    from twin.interface.backend import Backend
    from twin.session import RunOutcome

PHASES = ("close", "balance", "compress")
BALANCE_SPAN_COUNTS = 200.0
"""Travel over which a finger's stiffness is read during the balance (a span of ~4 sigma in its
positions): over 200 counts the 0.0085 N*m strain resolution is under a tenth of the slope's rise on
the softest foam the procedure answers for."""
BALANCE_MIN_T = 3.0
"""A finger's stiffness is read only where its torque follows its position: the slope's t statistic
(r sqrt((n - 2) / (1 - r^2)), n the readings' weight) at least this. A finger chattering on a faithful
foam's facets (its torque swinging over the gauge's range within a cycle) keeps the least gain; on a
16 kPa sphere the slope is read at t ~ 3.3 within the balance's first second."""
BALANCE_GAIN_CEILING = 10.0
"""The gain a measured stiffness may ask for, in multiples of the least: 10 covers the softest foam
measured (7e-5 N*m per count) at a 0.7 s time constant."""
BALANCE_MEMORY_S = 1.0
"""How long a balance reading weighs in the finger's stiffness: the touch's overshoot (the torque
relaxing while the finger still closes) is forgotten within the balance's first second."""
CAP_TORQUE_NM = float(units.strain_to_torque_nm(units.force_kg_to_strain(units.FINGERTIP_FORCE_LIMIT_KG)))
"""Distal torque (eq. 2) at the gauge reading where eq. 3 gives the 2 kg fingertip cap: 0.976 N*m."""
REACQUIRE_LEAD_COUNTS = 150.0
"""How far a re-closing finger's set point may lead its position: one 30 Hz cycle of the re-close
(100 counts) and some, so the twin re-closes unhindered and a late hand is not wound up."""


@dataclass(frozen=True, kw_only=True)
class CompressProfile:
    """Constants of the procedure; every one is a documented choice, see the module docstring."""

    close_velocity_counts_s: float = 12000.0
    """Approach speed: ~1.7 rad/s of the inner link, full closing in under 1.5 s. Fast enough that the
    touch breaks every clutch away on foams of 11-22 kPa too (at 6000 counts/s whether F1's and F2's
    did was a threshold in size and modulus, and near it the noise decided; docs/identification.md)."""
    contact_torque_nm: float = 0.10
    """A finger stops closing when its distal torque (eq. 2) rises this far above its no-load value..."""
    contact_samples: int = 2
    """...in this many consecutive readings: one reading over is a noise spike, not a grasp. The finger
    holds where the grasp is confirmed, not where the torque first crossed: stepping back to that
    first crossing would re-open the finger by a sample of travel (~200 counts), which re-couples a
    clutch the touch broke away (docs/identification.md) or not, depending on the gauge noise."""
    grasp_torque_nm: float = 0.20
    """Balanced grasp: every finger is servoed to this distal torque before compressing."""
    balance_s: float = 1.5
    """Shortest balance. It goes on until every finger's torque is within `balance_tolerance_nm` of
    the grasp torque, or `balance_timeout_s` has passed."""
    balance_tolerance_nm: float = 0.02
    """About four times the gauge noise (0.005 N*m): a balanced grasp, not one noisy reading."""
    balance_timeout_s: float = 5.0
    balance_gain_counts_per_nm_s: float = 2000.0
    """Least integral gain of the torque balance (counts per N*m of error per second): the gain where
    the finger's stiffness is not yet measured, and on stiff objects."""
    balance_settle_s: float = 0.5
    """The balance's time constant where the finger's stiffness is measured: the gain is 1 / (stiffness
    x this), within 1-BALANCE_GAIN_CEILING times `balance_gain_counts_per_nm_s`. A fixed gain that is
    stable on a firm block crawls on a soft foam (on a 16 kPa sphere under MuJoCo 4.0, 7e-5 N*m per
    count: a 4.5 s time constant that outlasted the balance's timeout)."""
    reacquire_velocity_counts_s: float = 3000.0
    """A finger whose load falls below half the contact torque during balance has lost the object
    (the fast touch of F1 and F2 can knock a block off the thumb): it closes at this speed until it
    feels the object again, instead of at the integral's crawl (0.2 N*m of error: 400 counts/s)."""
    offset_counts: float = 200.0
    amplitude_counts: float = 200.0
    """Eq. 7 offset and amplitude: 200 counts of drive ~ 2 mm at the fingertip after breakaway."""
    frequency_hz: float = 0.5
    phase_rad: float = -math.pi / 2
    """With offset = amplitude and phase -pi/2 the profile starts at the balanced grasp."""
    envelope: bool = True
    """Scale each finger's wave to keep it inside the hand's envelope (module docstring); False: the
    bare eq. 7 wave on every finger (runs recorded before the rule, re-simulated as they ran)."""
    cap_margin: float = 0.25
    """Fraction of the cap's torque kept free (a ceiling of 0.73 N*m). A finger is cut at its first
    reading over the ceiling, so the margin must hold a reading's rise: up to 0.22 N*m between two
    30 Hz readings in the library foams' default squeezes (F1 on the firm block). The highest reading of
    any of those runs' compressions is 0.77 N*m, 0.2 under the cap (docs/identification.md)."""
    close_timeout_s: float = 6.0
    spread_counts: float = 0.0
    """Spread 0: F1 and F2 side by side oppose the thumb F3, as in the paper's Fig. 3b."""

    def __post_init__(self) -> None:
        names = ("close_velocity_counts_s", "contact_torque_nm", "grasp_torque_nm", "balance_tolerance_nm")
        for name in (*names, "reacquire_velocity_counts_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"compress: {name} must be > 0")
        if self.contact_samples < 1:
            raise ConfigError("compress: contact_samples must be >= 1")
        if not 0 <= self.cap_margin < 1:
            raise ConfigError("compress: cap_margin must be in [0, 1)")
        if self.amplitude_counts < 0 or self.frequency_hz <= 0 or self.balance_s < 0:
            raise ConfigError("compress: amplitude >= 0, frequency > 0 and balance_s >= 0 required")
        if self.balance_timeout_s < self.balance_s:
            raise ConfigError("compress: balance_timeout_s must be >= balance_s")
        if self.offset_counts + self.amplitude_counts > 4000:
            raise ConfigError("compress: offset + amplitude above 4000 counts would crush the object")

    def to_json(self) -> dict[str, float]:
        """Plain-JSON constants for run metadata."""
        return dict(vars(self))


@dataclass
class CompressController:
    """State machine close -> balance -> compress, one step per hand reading."""

    profile: CompressProfile = field(default_factory=CompressProfile)
    phase: str = "close"
    _baseline_nm: np.ndarray | None = None
    _hold_counts: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _in_contact: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=bool))
    _over: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=int))
    _t_phase: float = 0.0
    _t_last: float | None = None
    _fit: np.ndarray = field(default_factory=lambda: np.zeros((6, 3)))
    """Sums n, p, tau, p^2, p*tau, tau^2 of each finger's balance readings: its stiffness by least
    squares."""
    grasp_counts: np.ndarray | None = None
    scale: float = 1.0
    """The share of the profile's wave the fingers follow (the envelope rule, module docstring)."""
    _stiffness_nm: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    _grasp_torque_nm: np.ndarray | None = None
    _below_counts: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Each finger's travel past its grasp set point at its latest reading under the ceiling."""
    _why: str = "the profile's amplitude: no finger's torque predicted or found at the ceiling"

    def __call__(self, reading: HandReading) -> HandCommand:
        """Next set points from the latest reading."""
        p = self.profile
        torque = units.strain_to_torque_nm(reading.strain_counts)
        position = reading.position_counts[:3].astype(float)
        if self._baseline_nm is None:
            self._baseline_nm = torque.copy()
            self._t_phase = reading.t_s
        dt = 0.0 if self._t_last is None else reading.t_s - self._t_last
        self._t_last = reading.t_s
        load = torque - self._baseline_nm
        if self.phase == "close":
            target = self._close(reading.t_s, position, load)
        elif self.phase == "balance":
            target = self._balance(reading.t_s, position, torque, load, dt)
        else:
            target = self._compress(reading.t_s, position, torque)
        return HandCommand(
            np.append(target, p.spread_counts),
            max_velocity_counts_s=p.close_velocity_counts_s,
        )

    def _close(self, t_s: float, position: np.ndarray, load: np.ndarray) -> np.ndarray:
        p = self.profile
        over = load > p.contact_torque_nm
        self._over = np.where(over, self._over + 1, 0)
        touched = ~self._in_contact & (self._over >= p.contact_samples)
        self._hold_counts[touched] = position[touched]
        self._in_contact |= touched
        target = np.where(self._in_contact, self._hold_counts, float(units.FINGER_FULL_COUNTS))
        if self._in_contact.all() or t_s - self._t_phase > p.close_timeout_s:
            self._hold_counts[~self._in_contact] = position[~self._in_contact]
            self._enter("balance", t_s)
        return target

    def _balance(
        self, t_s: float, position: np.ndarray, torque: np.ndarray, load: np.ndarray, dt: float
    ) -> np.ndarray:
        p = self.profile
        error = p.grasp_torque_nm - torque
        stiffness = self._stiffness(position, torque, dt)
        least = p.balance_gain_counts_per_nm_s
        gain = np.clip(1.0 / (stiffness * p.balance_settle_s), least, BALANCE_GAIN_CEILING * least)
        step = np.clip(gain * error * dt, -100.0, 100.0)
        lost = load < p.contact_torque_nm / 2
        # Re-close only while the finger keeps up with its set point: on a hand whose replies come a
        # cycle or two late the set point would otherwise run ahead and slam it into the object.
        keeping_up = self._hold_counts - position < REACQUIRE_LEAD_COUNTS
        step = np.where(lost, np.where(keeping_up, p.reacquire_velocity_counts_s * dt, 0.0), step)
        self._hold_counts = np.clip(self._hold_counts + step, 0, units.FINGER_FULL_COUNTS)
        elapsed = t_s - self._t_phase
        settled = not lost.any() and bool(np.all(np.abs(error) <= p.balance_tolerance_nm))
        if (elapsed >= p.balance_s and settled) or elapsed >= p.balance_timeout_s:
            self.grasp_counts = self._hold_counts.copy()
            self._choose_scale(stiffness, torque)
            self._enter("compress", t_s)
        return self._hold_counts

    def _stiffness(self, position: np.ndarray, torque: np.ndarray, dt: float) -> np.ndarray:
        """Each finger's distal torque per count of travel over its recent balance readings (least
        squares, weights fading over BALANCE_MEMORY_S so the touch's transient is forgotten); infinite
        (so the least gain) until the finger has moved about BALANCE_SPAN_COUNTS, or where the slope is
        not positive."""
        self._fit *= math.exp(-dt / BALANCE_MEMORY_S)
        self._fit += np.stack([np.ones(3), position, torque, position**2, position * torque, torque**2])
        n, sp, st, spp, spt, stt = self._fit
        var_p = spp / n - (sp / n) ** 2
        var_t = np.maximum(stt / n - (st / n) ** 2, 0.0)
        cov = spt / n - sp * st / n**2
        slope = cov / np.maximum(var_p, 1e-9)
        r2 = cov**2 / np.maximum(var_p * var_t, 1e-30)
        t2 = r2 * np.maximum(n - 2.0, 0.0) / np.maximum(1.0 - r2, 1e-12)  # the slope's t statistic, squared
        measured = (var_p >= (BALANCE_SPAN_COUNTS / 4) ** 2) & (slope > 0) & (t2 >= BALANCE_MIN_T**2)
        return np.where(measured, np.maximum(slope, 1e-12), np.inf)

    @property
    def ceiling_nm(self) -> float:
        """The distal torque no finger's squeeze should pass: `cap_margin` below the cap's."""
        return (1.0 - self.profile.cap_margin) * CAP_TORQUE_NM

    def _choose_scale(self, stiffness: np.ndarray, torque: np.ndarray) -> None:
        """The wave scaled so every finger's predicted peak torque (now + stiffness x peak travel) stays
        under the ceiling; a finger whose stiffness was not read sets no bound (watched on line)."""
        p = self.profile
        self._stiffness_nm = stiffness.copy()
        self._grasp_torque_nm = torque.copy()
        peak = p.offset_counts + p.amplitude_counts
        if not p.envelope or peak <= 0:  # a wave that never closes past the grasp needs no scale
            return
        rise = stiffness * peak
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(np.isfinite(rise) & (rise > 0), (self.ceiling_nm - torque) / rise, 1.0)
        k = int(np.argmin(share))
        if share[k] < 1:
            self.scale = float(max(share[k], 0.0))
            self._why = f"F{k + 1}'s peak torque predicted from its balance stiffness"

    def _watch(self, t_s: float, position: np.ndarray, torque: np.ndarray) -> None:
        """Cut the wave where a finger's torque crosses the ceiling (one reading: the gauge's noise is 50
        times smaller than the margin): from then on it takes that finger only as far as at its last
        reading under the ceiling."""
        p = self.profile
        below = torque <= self.ceiling_nm
        self._below_counts = np.where(below, position - self.grasp_counts, self._below_counts)
        peak = p.offset_counts + p.amplitude_counts
        for k in np.flatnonzero(~below):
            limit = max(float(self._below_counts[k]), 0.0) / peak if peak > 0 else 0.0
            if limit < self.scale:
                self.scale = limit
                t = t_s - self._t_phase
                self._why = f"cut {t:.2f} s into the compression, where F{k + 1}'s torque reached the ceiling"

    def _compress(self, t_s: float, position: np.ndarray, torque: np.ndarray) -> np.ndarray:
        p = self.profile
        if p.envelope:
            self._watch(t_s, position, torque)
        t = t_s - self._t_phase
        wave = p.offset_counts + p.amplitude_counts * math.sin(2 * math.pi * p.frequency_hz * t + p.phase_rad)
        return np.clip(self.grasp_counts + self.scale * wave, 0, units.FINGER_MAX_COUNTS)

    def run_metadata(self) -> dict:
        """run.json's `squeeze_amplitude`: the wave's amplitude and offset as the fingers followed it,
        and why."""
        p = self.profile
        peak = p.offset_counts + p.amplitude_counts
        grasp = self._grasp_torque_nm if self._grasp_torque_nm is not None else np.full(3, np.nan)
        finite = np.isfinite(self._stiffness_nm)
        return {
            "rule": (
                "the wave scaled so no finger's distal torque comes within cap_margin of the cap's: "
                "predicted from the balance stiffness, cut where a finger's torque still reached that ceiling"
                if p.envelope
                else "off: the profile's wave"
            ),
            "amplitude_counts": self.scale * p.amplitude_counts,
            "offset_counts": self.scale * p.offset_counts,
            "scale": self.scale,
            "why": self._why,
            "cap_torque_nm": CAP_TORQUE_NM,
            "ceiling_torque_nm": self.ceiling_nm,
            "fingers": ["F1", "F2", "F3"],
            "balance_stiffness_nm_per_kcount": [
                float(k * 1e3) if f else None for k, f in zip(self._stiffness_nm, finite, strict=True)
            ],
            "predicted_peak_torque_nm": [
                float(g + k * self.scale * peak) if f else None
                for g, k, f in zip(grasp, self._stiffness_nm, finite, strict=True)
            ],
        }

    def _enter(self, phase: str, t_s: float) -> None:
        self.phase = phase
        self._t_phase = t_s


def run_compress(
    backend: Backend,
    run_dir: Path | str,
    *,
    duration_s: float,
    object_name: str,
    profile: CompressProfile | None = None,
    progress: Callable[[float], None] | None = None,
    argv: list[str] | None = None,
    stereo_box: tuple[int, int, int, int] | None = None,
    shape_model: object = None,
    viewer: bool = True,
) -> RunOutcome:
    """The compress procedure on any backend, recorded to run_dir (what `twin run compress` does).

    `object_name` is what is in the hand: the sim knows it, on hardware it is the researcher's word.
    `stereo_box`: where the backend has cameras, the object's box on the first frame (see run_experiment).
    `shape_model`: a trained twin.shape.model.ShapeModel predicting the contour live (`--predict`).
    `viewer=False`: no run.rrd (the twin's own simulations, which read the streams alone).
    """
    from twin.session import run_experiment

    profile = profile or CompressProfile()
    return run_experiment(
        backend=backend,
        controller=CompressController(profile),
        phases=PHASES,
        duration_s=duration_s,
        run_dir=Path(run_dir),
        experiment={"name": "compress", "object": object_name, "profile": profile.to_json()},
        progress=progress,
        argv=argv,
        stereo_box=stereo_box,
        shape_model=shape_model,
        viewer=viewer,
    )
