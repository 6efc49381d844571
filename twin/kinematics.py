"""Where the hand's links and taxels are, from the encoder counts alone (backend-free).

The BH8 measures only its motors. Each finger's drive angle (encoder counts, eq. 1 scale) sets both
links while the TorqueSwitch is coupled (inner = drive, outer = drive / 3); once the inner link is
stopped the clutch breaks away and only the outer link keeps closing, at 4/3 of the drive (paper §3.1).
The breakaway is not measured either: `ClutchObserver` places it at the first firm load on the finger
(the distal strain gauge rising `BREAKAWAY_LOAD_NM` above its no-load value while closing), which is
where a finger that meets an object is stopped. Measured on the twin's library foams (compress runs,
`twin.sim` truth): link angles within 0.9 deg on block, sphere and cylinder F1/F2, 3.1 deg on the
cylinder's F3 and 5.2 deg on soft_block's F1/F2, whose soft contact breaks away later.

Link poses come from the hand's own MJCF (models/barrett_mjcf/bh8.xml) through MuJoCo's forward
kinematics: the model is the kinematic description; nothing is simulated.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from twin import units
from twin.assets import HAND_XML
from twin.tactile.layout import LAYOUT

HAND_FRAME_BODY = "palm"
"""The hand frame of every 3-D quantity (cameras, clouds, contacts): the palm body's frame."""
BREAKAWAY_LOAD_NM = 0.08
"""Distal torque above no-load (eq. 2) that marks the finger's first firm contact, i.e. its breakaway."""
RECOUPLE_MARGIN_RAD = 0.01
"""Opening this far (~70 counts) below the breakaway point re-couples (a margin against dither)."""


class ClutchObserver:
    """Estimates each finger's drive angle at breakaway from the strain gauges while it closes."""

    def __init__(self, load_nm: float = BREAKAWAY_LOAD_NM) -> None:
        self.load_nm = load_nm
        self.baseline_nm: NDArray[np.float64] | None = None
        self.breakaway_rad = np.full(3, np.inf)
        """Drive angle (inner-link rad) where each clutch broke away; inf while coupled."""

    def update(self, position_counts: ArrayLike, strain_counts: ArrayLike) -> NDArray[np.float64]:
        """Take one hand reading; returns (3, 2) inner and outer link angles (rad) of F1-F3."""
        drive = units.finger_counts_to_inner_rad(np.asarray(position_counts)[:3])
        torque = units.strain_to_torque_nm(np.asarray(strain_counts)[:3])
        if self.baseline_nm is None:
            self.baseline_nm = torque.copy()
        loaded = (torque - self.baseline_nm > self.load_nm) & np.isinf(self.breakaway_rad)
        self.breakaway_rad[loaded] = drive[loaded]
        reopened = drive < self.breakaway_rad - RECOUPLE_MARGIN_RAD  # opening past it re-couples
        self.breakaway_rad[reopened] = np.inf
        return link_angles(drive, self.breakaway_rad)


def link_angles(drive_rad: ArrayLike, breakaway_rad: ArrayLike) -> NDArray[np.float64]:
    """(3, 2) inner and outer link angles for drive angles and breakaway points (inf: coupled)."""
    drive = np.asarray(drive_rad, dtype=float)
    b = np.asarray(breakaway_rad, dtype=float)
    b_reached = np.minimum(drive, b)  # the drive at breakaway, or the drive itself while coupled
    inner = b_reached
    outer = units.OUTER_RATIO_COUPLED * b_reached + units.OUTER_RATIO_BROKEN_AWAY * (drive - b_reached)
    return np.stack([inner, outer], axis=1)


class HandKinematics:
    """Forward kinematics of the BH8 from link angles: link poses and taxel positions in the hand frame."""

    def __init__(self, xml_path: Path = HAND_XML) -> None:
        self.model = mujoco.MjModel.from_xml_path(str(xml_path))
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._inner = [m.joint(f"f{k}_inner").qposadr[0] for k in (1, 2, 3)]
        self._outer = [m.joint(f"f{k}_outer").qposadr[0] for k in (1, 2, 3)]
        self._spread = [m.joint(f"f{k}_spread").qposadr[0] for k in (1, 2)]
        self._palm = m.body(HAND_FRAME_BODY).id
        self._taxel_body = np.array([m.body(LAYOUT.pads[p].body).id for p in LAYOUT.pad_index])
        self._taxel_pos = LAYOUT.position_m
        self._taxel_normal = LAYOUT.normal
        self.posed = False
        """Whether set_angles was called (before it: the open hand's zero pose)."""
        mujoco.mj_kinematics(self.model, self.data)

    def set_angles(self, links_rad: ArrayLike, spread_rad: float) -> None:
        """Pose the hand: (3, 2) inner/outer angles of F1-F3 and the spread angle."""
        links = np.asarray(links_rad, dtype=float)
        d = self.data
        d.qpos[self._inner] = links[:, 0]
        d.qpos[self._outer] = links[:, 1]
        d.qpos[self._spread] = spread_rad
        mujoco.mj_kinematics(self.model, d)
        self.posed = True

    def body_pose(self, body: str) -> NDArray[np.float64]:
        """4x4 pose of a body in the hand frame, at the last set_angles."""
        return self._hand_from_world() @ _pose(self.data, self.model.body(body).id)

    def _hand_from_world(self) -> NDArray[np.float64]:
        return np.linalg.inv(_pose(self.data, self._palm))

    def taxels(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(162, 3) taxel centres and (162, 3) outward normals in the hand frame, at the last set_angles."""
        d = self.data
        rot = d.xmat[self._taxel_body].reshape(-1, 3, 3)
        world = d.xpos[self._taxel_body] + np.einsum("nij,nj->ni", rot, self._taxel_pos)
        normal = np.einsum("nij,nj->ni", rot, self._taxel_normal)
        hand = self._hand_from_world()
        return world @ hand[:3, :3].T + hand[:3, 3], normal @ hand[:3, :3].T


def _pose(data: mujoco.MjData, body: int) -> NDArray[np.float64]:
    t = np.eye(4)
    t[:3, :3] = data.xmat[body].reshape(3, 3)
    t[:3, 3] = data.xpos[body]
    return t
