"""The BH8 TorqueSwitch (breakaway clutch), switched on MuJoCo equality constraints.

Coupled: inner = drive, outer = drive/3 (gear ratios 125:1 and 375:1). When the torque the clutch
passes to the inner link exceeds the breakaway threshold while closing, the inner link is locked
where it is and the outer link keeps closing at 4/3 of the drive (4/375 vs 1/125, paper §3.1).
Opening the drive back past the breakaway point re-couples the finger (opening resets the clutch):
commanded there and moved there, not a holding drive that overshoots or sags under the finger's load.
The BH8's worm drives are not back-drivable; the twin's drive is a position servo (kp 100 N*m/rad) that
dips 8-16 counts below a set point held at the breakaway point. A finger whose touch was confirmed as its
clutch slipped was re-coupled by that dip on some noise seeds and not others, and its inner link then
closed on with the balance: one grasp or another by chance (docs/identification.md, *What `grasp` is
made of*).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from twin import units

BREAKAWAY_TORQUE_NM = 0.5
"""Inner-link torque at which the clutch slips (GraspIt! Barrett.xml <breakAwayTorque>)."""


@dataclass
class FingerClutch:
    """Equality ids and joint addresses of one finger's clutch, plus its state."""

    couple_inner: int
    couple_outer: int
    lock: int
    inner_qpos: int
    outer_qpos: int
    drive_qpos: int
    broken_away: bool = False
    drive_at_breakaway_rad: float = 0.0


class Clutches:
    """The three TorqueSwitches; call update() after every mj_step."""

    def __init__(self, model: mujoco.MjModel, threshold_nm: float = BREAKAWAY_TORQUE_NM) -> None:
        self.model = model
        self.threshold_nm = threshold_nm
        self.fingers = [self._finger(model, k) for k in (1, 2, 3)]
        self._eq_inner = [f.couple_inner for f in self.fingers]
        self._eq_outer = [f.couple_outer for f in self.fingers]
        self._drive_qpos = np.array([f.drive_qpos for f in self.fingers])
        self.inner_torque_nm = np.zeros(3)
        self.outer_torque_nm = np.zeros(3)

    @staticmethod
    def _finger(model: mujoco.MjModel, k: int) -> FingerClutch:
        def eq(name: str) -> int:
            return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, f"f{k}_{name}")

        return FingerClutch(
            couple_inner=eq("couple_inner"),
            couple_outer=eq("couple_outer"),
            lock=eq("clutch_lock"),
            inner_qpos=model.joint(f"f{k}_inner").qposadr[0],
            outer_qpos=model.joint(f"f{k}_outer").qposadr[0],
            drive_qpos=model.joint(f"f{k}_drive").qposadr[0],
        )

    @property
    def broken_away(self) -> np.ndarray:
        """(3,) bool: which fingers are past breakaway."""
        return np.array([f.broken_away for f in self.fingers])

    def reset(self, data: mujoco.MjData) -> None:
        """Re-couple every finger (power-up state)."""
        for f in self.fingers:
            self._couple(f, data)

    def update(self, data: mujoco.MjData) -> None:
        """Read the coupling torques of the last step and switch clutches that slip or re-engage.

        Runs after every step: the three fingers' values are read in one go as Python floats (numpy
        per-element indexing and small-array ops cost more than the decision itself)."""
        self._read_coupling_torques(data)
        drives = data.qpos[self._drive_qpos].tolist()
        set_points = data.ctrl[:3].tolist()
        torques = self.inner_torque_nm.tolist()
        for f, drive, set_point, torque in zip(self.fingers, drives, set_points, torques, strict=True):
            if not f.broken_away:
                if set_point > drive and torque > self.threshold_nm:  # closing and slipping
                    self._break_away(f, data)
            elif drive <= f.drive_at_breakaway_rad and set_point < f.drive_at_breakaway_rad:
                self._couple(f, data)  # opened: commanded, and moved, back past the breakaway point

    def _read_coupling_torques(self, data: mujoco.MjData) -> None:
        """Torque each coupling applies to its link joint: efc_force of its equality row.

        A joint equality q1 = poly(q2) has Jacobian +1 on q1, so its row's force is the torque on q1.
        MuJoCo puts the equality rows first: the first data.ne rows are all of them.
        """
        ne = data.ne
        ids, forces = data.efc_id[:ne].tolist(), data.efc_force[:ne].tolist()  # a few rows: as lists
        torque = dict(zip(reversed(ids), reversed(forces), strict=True))  # by equality id; its first row
        self.inner_torque_nm[:] = [torque.get(e, 0.0) for e in self._eq_inner]  # inactive: no row, 0
        self.outer_torque_nm[:] = [torque.get(e, 0.0) for e in self._eq_outer]

    def _break_away(self, f: FingerClutch, data: mujoco.MjData) -> None:
        drive = data.qpos[f.drive_qpos]
        inner = data.qpos[f.inner_qpos]
        outer = data.qpos[f.outer_qpos]
        f.broken_away = True
        f.drive_at_breakaway_rad = drive
        m = self.model
        m.eq_data[f.lock, 0] = inner
        ratio = units.OUTER_RATIO_BROKEN_AWAY
        m.eq_data[f.couple_outer, 0] = outer - ratio * drive
        m.eq_data[f.couple_outer, 1] = ratio
        data.eq_active[f.lock] = 1
        data.eq_active[f.couple_inner] = 0

    def _couple(self, f: FingerClutch, data: mujoco.MjData) -> None:
        f.broken_away = False
        m = self.model
        m.eq_data[f.couple_outer, 0] = 0.0
        m.eq_data[f.couple_outer, 1] = units.OUTER_RATIO_COUPLED
        data.eq_active[f.couple_inner] = 1
        data.eq_active[f.lock] = 0
