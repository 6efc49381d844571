"""The simulated PPS pads: contact forces binned over the taxel areas, then raw 15-bit counts.

Each contact touching a pad's link on its sensing face (within `FACE_DEPTH_M` of the face and
`EDGE_MARGIN_M` of the grid) has its normal force spread over the pad's taxels with a normalized
Gaussian of width `SPREAD_SIGMA_M` (a fingertip-sized patch of foam presses on several cells; a
flexcomp's contacts are a few millimetres to a centimetre apart). Spreading conserves the force, so
eq. 6 on the binned pressures returns the contact force on the pad up to noise, quantization and
calibration error. Why binning rather than MuJoCo's tactile sensor or the touch_grid plugin:
docs/tactile_methods.md.

The sensor itself: each taxel has its own true line (gain and offset spread as on a real pad); the
reading is the inverse of that line, plus Gaussian noise, rounded and saturated to 0-32767. The
manufacturer-style 7-point calibration of those lines, with reading noise, is what the rig's
conversion (eq. 5) loads from the files the backend writes: the conversion code runs exactly as it
would on the hand.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from numpy.typing import NDArray

from twin.interface.devices import N_TAXELS, TAXEL_COUNT_MAX, TactileArray, TactileReading
from twin.interface.specs import DeviceSpec
from twin.interface.tactile_spec import TactileConfig, tactile_device_spec
from twin.sim.world import SimWorld
from twin.tactile.calibration import (
    CALIBRATION_POINTS_KPA,
    TaxelCalibration,
    fit_lines,
    write_points,
    write_table,
)
from twin.tactile.layout import LAYOUT

SPREAD_SIGMA_M = 0.003
"""Width of the patch one contact presses on: half a 6 mm cell."""
FACE_DEPTH_M = 0.004
"""Contacts up to this far behind the sensing face count (penetration, the rounded tip)."""
EDGE_MARGIN_M = 0.006
"""Contacts this far beyond the outer cells still land on the pad (its border cells)."""
GAIN_KPA_PER_COUNT = 0.0125
"""Mean slope a_i: ~400 kPa at full scale, above 2 kg on four 6 mm cells (~136 kPa)."""
GAIN_SPREAD = 0.08
"""Relative spread of the slopes between taxels."""
ZERO_COUNT_MEAN, ZERO_COUNT_STD = 500.0, 60.0
"""Reading of an unloaded taxel and its spread (the offset b_i = -a_i * zero count)."""
CALIBRATION_NOISE_COUNTS = 3.0
"""Reading noise of the calibration rig's 7 points."""


@dataclass(frozen=True)
class SimTactileSensor:
    """The simulated pads' true per-taxel lines and the calibration points measured on them."""

    true: TaxelCalibration
    points_taxel: NDArray[np.int64]
    points_kpa: NDArray[np.float64]
    points_counts: NDArray[np.int64]

    @classmethod
    def generate(cls, seed: int) -> SimTactileSensor:
        """A pad set with a realistic spread of lines, calibrated at 7 pressures (deterministic)."""
        rng = np.random.default_rng([seed, 5])  # its own stream: the pads are one physical part
        a = GAIN_KPA_PER_COUNT * np.clip(rng.normal(1.0, GAIN_SPREAD, N_TAXELS), 0.7, 1.3)
        zero = rng.normal(ZERO_COUNT_MEAN, ZERO_COUNT_STD, N_TAXELS).clip(200, 900)
        true = TaxelCalibration(a, -a * zero, "simulated")
        taxel = np.repeat(np.arange(N_TAXELS), len(CALIBRATION_POINTS_KPA))
        kpa = np.tile(CALIBRATION_POINTS_KPA, N_TAXELS)
        counts = (kpa - true.b_kpa[taxel]) / a[taxel] + rng.normal(0, CALIBRATION_NOISE_COUNTS, kpa.size)
        counts = np.clip(np.round(counts), 0, TAXEL_COUNT_MAX).astype(np.int64)
        return cls(true, taxel, kpa, counts)

    def write_files(self, directory: Path) -> dict[str, Path]:
        """The points file and the fitted look-up table, as a manufacturer would ship them."""
        directory.mkdir(parents=True, exist_ok=True)
        points = write_points(
            self.points_taxel,
            self.points_kpa,
            self.points_counts,
            directory / "tactile_points.csv",
            "(simulated)",
        )
        fitted = fit_lines(self.points_taxel, self.points_kpa, self.points_counts, str(points))
        table = write_table(fitted, directory / "tactile_table.csv", "Fitted to tactile_points.csv.")
        return {"tactile_points": points, "tactile_table": table}


class _Pad:
    """Per-pad constants for binning: body, frame, taxel coordinates on the pad plane."""

    def __init__(self, model: mujoco.MjModel, index: int) -> None:
        spec = LAYOUT.pads[index]
        self.body = model.body(spec.body).id
        self.ids = LAYOUT.taxels_of(spec.name)
        self.origin = np.array(spec.origin_m)
        self.u, self.v, self.n = (np.array(a, dtype=float) for a in (spec.u_axis, spec.v_axis, spec.normal))
        rel = LAYOUT.position_m[self.ids] - self.origin
        self.uv = np.column_stack([rel @ self.u, rel @ self.v])
        lo, hi = self.uv.min(axis=0) - EDGE_MARGIN_M, self.uv.max(axis=0) + EDGE_MARGIN_M
        self.lo, self.hi = lo, hi


class SimTactile(TactileArray):
    """The 162 taxels on a SimWorld, scanned on demand."""

    def __init__(
        self, world: SimWorld, config: TactileConfig, sensor: SimTactileSensor, rng: np.random.Generator
    ) -> None:
        super().__init__()
        self.world = world
        self.config = config
        self.sensor = sensor
        self._spec = tactile_device_spec(config)
        self._rng = rng
        model = world.model
        self._pads = [_Pad(model, k) for k in range(len(LAYOUT.pads))]
        self._pad_of_body = np.full(model.nbody, -1)
        for k, pad in enumerate(self._pads):
            self._pad_of_body[pad.body] = k
        self._pyramidal = model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
        self.contact_points_m = np.zeros((0, 3))
        """World positions of the contacts binned by the last scan."""
        self.contact_forces_n = np.zeros((0, 3))
        """Their normal force vectors (N), pointing into the pad."""

    @property
    def spec(self) -> DeviceSpec:
        """Declared rate, latency and channel."""
        return self._spec

    def _connect(self) -> None:
        pass

    def _disconnect(self) -> None:
        pass

    def taxel_forces_n(self) -> NDArray[np.float64]:
        """(162,) normal force on each taxel now: contact forces binned over the pads (vectorized)."""
        m, d = self.world.model, self.world.data
        forces = np.zeros(N_TAXELS)
        points, vectors = [np.zeros((0, 3))], [np.zeros((0, 3))]
        if d.ncon:
            contact = d.contact
            geom = contact.geom
            bodies = np.where(geom >= 0, m.geom_bodyid[np.maximum(geom, 0)], -1)
            pad_side = np.where(bodies >= 0, self._pad_of_body[np.maximum(bodies, 0)], -1)
            touching = np.flatnonzero((pad_side >= 0).any(axis=1) & (contact.efc_address >= 0))
            normal = self._normal_forces(touching) if touching.size else np.zeros(0)
            for k, pad in enumerate(self._pads):
                on_pad = (pad_side[touching] == k).any(axis=1) & (normal > 0)
                if not on_pad.any():
                    continue
                idx = touching[on_pad]
                fn = normal[on_pad]
                rot = d.xmat[pad.body].reshape(3, 3)
                local = (contact.pos[idx] - d.xpos[pad.body]) @ rot - pad.origin
                uv = np.column_stack([local @ pad.u, local @ pad.v])
                keep = (local @ pad.n >= -FACE_DEPTH_M) & np.all((uv >= pad.lo) & (uv <= pad.hi), axis=1)
                if not keep.any():
                    continue
                uv, fn, idx = uv[keep], fn[keep], idx[keep]
                dist2 = np.sum((uv[:, None, :] - pad.uv[None, :, :]) ** 2, axis=2)
                weights = np.exp(-dist2 / (2 * SPREAD_SIGMA_M**2))
                total = weights.sum(axis=1)
                lost = total < 1e-12  # far from every cell centre: the nearest cell takes it
                if lost.any():
                    weights[lost] = 0.0
                    weights[lost, np.argmin(dist2[lost], axis=1)] = 1.0
                    total[lost] = 1.0
                forces[pad.ids] += (fn / total) @ weights
                points.append(contact.pos[idx])
                vectors.append(-fn[:, None] * (rot @ pad.n)[None, :])
        self.contact_points_m = np.concatenate(points)
        self.contact_forces_n = np.concatenate(vectors)
        return forces

    def _normal_forces(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        """Normal force of contacts idx (as mj_contactForce gives it, without its per-call cost)."""
        d = self.world.data
        adr = d.contact.efc_address[idx]
        if not self._pyramidal:
            return d.efc_force[adr].copy()
        rows = np.maximum(2 * (d.contact.dim[idx] - 1), 1)  # pyramid edges; frictionless: one row
        out = np.zeros(idx.size)
        for r in np.unique(rows):
            sel = rows == r
            out[sel] = d.efc_force[adr[sel, None] + np.arange(r)].sum(axis=1)
        return out

    def pressure_kpa(self) -> NDArray[np.float64]:
        """(162,) true pressure on each taxel now (force over area), before the sensor."""
        return self.taxel_forces_n() / LAYOUT.area_m2 / 1e3

    def read(self) -> TactileReading:
        """One scan: pressures through each taxel's true line, noise, 15-bit quantization, saturation."""
        self._require_connection()
        counts = self.sensor.true.to_counts(self.pressure_kpa())
        counts = counts + self._rng.normal(0.0, self.config.noise_counts, N_TAXELS)
        counts = np.clip(np.round(counts), 0, TAXEL_COUNT_MAX).astype(np.int32)
        return TactileReading(t_s=self.world.time_s, counts=counts)
