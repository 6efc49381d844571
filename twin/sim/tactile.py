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


def contact_frame_forces(
    data: mujoco.MjData, idx: NDArray[np.int64], pyramidal: bool, *, tangents: bool = True
) -> NDArray[np.float64]:
    """(n, 3) force of contacts idx in their contact frames (normal, then the two tangents), as
    mj_contactForce gives its first three components, for all of them at once (no per-call cost);
    without `tangents`, the normal only (the others left 0).

    Pyramidal cones keep 2 (dim - 1) edge forces: the normal is their sum and tangent i is
    (edge 2i - edge 2i+1) * friction i (mju_decodePyramid); elliptic cones keep the force itself."""
    contact = data.contact
    adr, dim = contact.efc_address[idx], contact.dim[idx]
    out = np.zeros((idx.size, 3))
    if not idx.size:
        return out
    rows = np.maximum(2 * (dim - 1), 1) if pyramidal else dim  # a frictionless contact: one row
    first = int(rows[0])
    uniform = bool((rows == first).all())  # the usual case: every contact of one condim
    for r in [first] if uniform else np.unique(rows).tolist():
        sel = slice(None) if uniform else rows == r
        f = data.efc_force[adr[sel, None] + np.arange(r)]
        if not pyramidal:
            out[sel, : min(r, 3) if tangents else 1] = f[:, : 3 if tangents else 1]
            continue
        out[sel, 0] = f.sum(axis=1)
        pairs = min(r // 2, 2) if tangents and r > 1 else 0
        if pairs:
            friction = contact.friction[idx[sel], :pairs]
            out[sel, 1 : 1 + pairs] = (f[:, 0 : 2 * pairs : 2] - f[:, 1 : 2 * pairs : 2]) * friction
    return out


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
        # The pads' constants stacked, so that a scan bins the contacts of every pad at once.
        pads = self._pads
        self._pad_body = np.array([p.body for p in pads])
        self._pad_origin = np.array([p.origin for p in pads])
        self._pad_axes = np.array([[p.u, p.v, p.n] for p in pads])  # (pads, 3, 3): rows u, v, normal
        self._pad_lo, self._pad_hi = np.array([p.lo for p in pads]), np.array([p.hi for p in pads])
        width = max(p.ids.size for p in pads)
        self._pad_taxels = np.full((len(pads), width), N_TAXELS)  # padding: a taxel past the last
        self._pad_uv = np.full((len(pads), width, 2), np.inf)  # padding: infinitely far, weight 0
        for k, p in enumerate(pads):
            self._pad_taxels[k, : p.ids.size] = p.ids
            self._pad_uv[k, : p.ids.size] = p.uv
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
        """(162,) normal force on each taxel now: contact forces binned over the pads.

        Every (contact, pad) pair is binned at once, pad by pad in contact order (the order of
        contact_points_m); a contact between two pads counts on each."""
        m, d = self.world.model, self.world.data
        self.contact_points_m, self.contact_forces_n = np.zeros((0, 3)), np.zeros((0, 3))
        if not d.ncon:
            return np.zeros(N_TAXELS)
        contact = d.contact
        geom = contact.geom
        bodies = np.where(geom >= 0, m.geom_bodyid[np.maximum(geom, 0)], -1)
        pad_side = np.where(bodies >= 0, self._pad_of_body[np.maximum(bodies, 0)], -1)
        touching = np.flatnonzero((pad_side >= 0).any(axis=1) & (contact.efc_address >= 0))
        if not touching.size:
            return np.zeros(N_TAXELS)
        normal = self._normal_forces(touching)
        side = pad_side[touching]
        pad = side.T.reshape(-1)  # each contact's first side's pad, then its second side's
        row = np.tile(np.arange(touching.size), 2)
        valid = (pad >= 0) & (normal[row] > 0)
        valid[touching.size :] &= side[:, 1] != side[:, 0]
        pad, row = pad[valid], row[valid]
        order = np.lexsort((row, pad))
        pad, row = pad[order], row[order]
        idx, fn = touching[row], normal[row]
        body = self._pad_body[pad]
        rot = d.xmat[body].reshape(-1, 3, 3)
        pos = contact.pos[idx]
        local = np.einsum("pj,pjk->pk", pos - d.xpos[body], rot) - self._pad_origin[pad]
        uvn = np.einsum("pk,pak->pa", local, self._pad_axes[pad])  # on the pad: u, v, height
        uv = uvn[:, :2]
        in_grid = np.all((uv >= self._pad_lo[pad]) & (uv <= self._pad_hi[pad]), axis=1)
        keep = (uvn[:, 2] >= -FACE_DEPTH_M) & in_grid
        if not keep.any():
            return np.zeros(N_TAXELS)
        pad, uv, fn, pos, rot = pad[keep], uv[keep], fn[keep], pos[keep], rot[keep]
        dist2 = np.sum((uv[:, None, :] - self._pad_uv[pad]) ** 2, axis=2)
        weights = np.exp(-dist2 / (2 * SPREAD_SIGMA_M**2))
        total = weights.sum(axis=1)
        lost = total < 1e-12  # far from every cell centre: the nearest cell takes it
        if lost.any():
            weights[lost] = 0.0
            weights[lost, np.argmin(dist2[lost], axis=1)] = 1.0
            total[lost] = 1.0
        share = (fn / total)[:, None] * weights
        forces = np.bincount(self._pad_taxels[pad].reshape(-1), share.reshape(-1), N_TAXELS + 1)
        self.contact_points_m = pos
        self.contact_forces_n = -fn[:, None] * np.einsum("pij,pj->pi", rot, self._pad_axes[pad, 2])
        return forces[:N_TAXELS]

    def _normal_forces(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        """Normal force of contacts idx (as mj_contactForce gives it, without its per-call cost)."""
        return contact_frame_forces(self.world.data, idx, self._pyramidal, tangents=False)[:, 0]

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
