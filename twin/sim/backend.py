"""The simulation backend: a composed MuJoCo scene, its devices and a sim-time clock."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from twin.assets import HAND_XML
from twin.interface.backend import Backend, Clock, stereo_calibration_key
from twin.interface.hand_spec import HandConfig
from twin.interface.stereo_spec import StereoConfig
from twin.interface.tactile_spec import TactileConfig
from twin.kinematics import HAND_FRAME_BODY
from twin.sim.foam import FoamParams
from twin.sim.hand import SimHand
from twin.sim.scene import build_model
from twin.sim.tactile import SimTactile, SimTactileSensor, contact_frame_forces
from twin.sim.world import DEFAULT_HINT, SimWorld

if TYPE_CHECKING:  # the cameras and the vision stack are imported only by a backend with cameras
    from twin.sim.cameras import CameraPlacement, SimStereo
    from twin.sim.surface_truth import SurfaceScorer, SurfaceTruth
    from twin.vision.reconstruct import Box, Rectifier

FINGERS = (1, 2, 3)
STEREO_CALIBRATION_FILE = "stereo_calibration.json"


def _calibration(foam: FoamParams | None) -> dict[str, Any] | None:
    """The scale on the foam's flex modulus and where it came from (twin.sim.calibration)."""
    if foam is None:
        return None
    from twin.sim.calibration import scale_of

    return scale_of(foam).to_json()


def _divergence_hint(foam: FoamParams | None) -> str:
    """What to change when this scene's physics diverges: the object's modulus or damping."""
    if foam is None:
        return DEFAULT_HINT
    return (
        f"the object ({foam.name}: E = {foam.young_pa:g} Pa, damping {foam.damping:g} s) is too stiff or "
        "too damped for the physics step; use a smaller --young or --damping (the library's objects "
        "have E = 15-150 kPa, damping 0.002 s)"
    )


class SimClock(Clock):
    """Sim time: advancing it steps the physics as fast as the machine allows."""

    def __init__(self, world: SimWorld) -> None:
        self.world = world

    def now(self) -> float:
        """Sim time (s)."""
        return self.world.time_s

    def advance_to(self, t_s: float) -> None:
        """Step the physics up to t_s."""
        self.world.advance_to(t_s)


class SimBackend(Backend):
    """Hand, tactile pads and optionally the stereo pair on one MuJoCo world; deterministic for a seed."""

    name = "sim"

    def __init__(
        self,
        foam: FoamParams | None,
        hand_config: HandConfig | None = None,
        seed: int = 0,
        *,
        tactile_config: TactileConfig | None = None,
        tactile: bool = True,
        stereo_config: StereoConfig | None = None,
        stereo: bool = False,
        stereo_render_native: bool = False,
        stereo_calibration_file: Path | None = None,
        stereo_placement: CameraPlacement | Sequence[CameraPlacement] | None = None,
    ) -> None:
        """`stereo_placement`: where the pair stands (twin.sim.cameras.PLACEMENTS; None: the scene's
        default, DEFAULT_PLACEMENT); a sequence puts one pair at each (`stereo_pairs`, the first of
        which is `stereo`). `stereo_render_native`: render the cameras at 640x480 and
        area-average to 320x240 (as a camera read out and scaled) instead of at 320x240 directly.
        Off by default: on 2 cores it takes a run with cameras from ~1.3x to ~1.0x real time
        (BENCHMARKS.md), and the direct render reconstructs as accurately (block, 10 s: median 0.32
        vs 0.36 mm, coverage 72 vs 69 %)."""
        if stereo_calibration_file is not None:
            from twin.vision.calibration import StereoCalibration

            StereoCalibration.load(stereo_calibration_file)  # a bad file fails here, before any run
        self.stereo_calibration_file = stereo_calibration_file
        self.foam = foam
        self.seed = seed
        self.world = SimWorld(
            build_model(foam, cameras=stereo, camera_placement=stereo_placement), hint=_divergence_hint(foam)
        )
        rng = np.random.default_rng(seed)
        self.hand = SimHand(self.world, hand_config or HandConfig(), rng)
        self.tactile = (
            SimTactile(
                self.world,
                tactile_config or TactileConfig(),
                SimTactileSensor.generate(seed),
                np.random.default_rng([seed, 1]),  # its own noise stream: hand readings stay as they were
            )
            if tactile
            else None
        )
        self.stereo: SimStereo | None = None
        self.stereo_pairs: list[SimStereo] = []
        """Every pair of the rig, `stereo` first (one per placement)."""
        self.stereo_placements: list[str] = []
        """Where each pair of `stereo_pairs` stands (twin.sim.cameras.CameraPlacement.name)."""
        if stereo:
            from twin.sim.cameras import DEFAULT_PLACEMENT, SimStereo, pair_camera_names

            placements = stereo_placement if isinstance(stereo_placement, Sequence) else [stereo_placement]
            self.stereo_placements = [DEFAULT_PLACEMENT if p is None else p.name for p in placements]
            if len(set(self.stereo_placements)) < len(self.stereo_placements):
                raise ValueError(f"camera placements named twice: {', '.join(self.stereo_placements)}")
            n_pairs = len(placements)
            self.stereo_pairs = [
                SimStereo(
                    self.world,
                    stereo_config or StereoConfig(),
                    np.random.default_rng([seed, 2] if pair == 0 else [seed, 2, pair]),
                    render_native=stereo_render_native,
                    cameras=pair_camera_names(pair),
                )
                for pair in range(n_pairs)
            ]
            self.stereo = self.stereo_pairs[0]
        self._scorer: SurfaceScorer | None = None
        self._clock = SimClock(self.world)
        m = self.world.model
        self._inner = [m.joint(f"f{k}_inner").qposadr[0] for k in FINGERS]
        self._outer = [m.joint(f"f{k}_outer").qposadr[0] for k in FINGERS]
        self._spread = m.joint("f1_spread").qposadr[0]
        self._outer_bodies = np.array([m.body(f"f{k}_outer").id for k in FINGERS])
        self._pyramidal = m.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL

    def devices(self) -> list[Any]:
        """The devices present, hand first, every stereo pair last."""
        return [d for d in (self.hand, self.tactile) if d is not None] + list(self.stereo_pairs)

    def named_stereo_pairs(self) -> list[tuple[str, SimStereo]]:
        """Every pair with its placement's name, `stereo` first."""
        return list(zip(self.stereo_placements, self.stereo_pairs, strict=True))

    @property
    def clock(self) -> Clock:
        """Sim-time clock."""
        return self._clock

    @property
    def is_simulated(self) -> bool:
        """Sim time: the rig never sleeps."""
        return True

    def ground_truth(self) -> Mapping[str, np.ndarray]:
        """Link angles, distal torques, clutch states and fingertip contact forces now."""
        d = self.world.data
        return {
            "inner_rad": d.qpos[self._inner],  # indexed by a list: already copies
            "outer_rad": d.qpos[self._outer],
            "spread_rad": np.float64(d.qpos[self._spread]),
            "distal_torque_nm": self.world.clutches.outer_torque_nm.copy(),
            "broken_away": self.world.clutches.broken_away,
            "tip_contact_force_n": self.fingertip_contact_force_n(),
        }

    def fingertip_contact_force_n(self) -> np.ndarray:
        """(3,) magnitude of the summed contact force on each outer link (N)."""
        m, d = self.world.model, self.world.data
        total = np.zeros((3, 3))
        if d.ncon:  # all contacts at once (a per-contact loop cost ~0.1 ms a sample)
            contact = d.contact
            geom = contact.geom
            bodies = np.where(geom >= 0, m.geom_bodyid[np.maximum(geom, 0)], -1)
            touches = (bodies[:, :, None] == self._outer_bodies).any(axis=1)  # (ncon, 3 fingers)
            idx = np.flatnonzero(touches.any(axis=1) & (contact.efc_address >= 0))  # no row: no force
            if idx.size:
                local = contact_frame_forces(d, idx, self._pyramidal)
                world = np.einsum("nij,ni->nj", contact.frame[idx].reshape(-1, 3, 3), local)  # frame.T @ f
                total = touches[idx].T.astype(float) @ world
        return np.linalg.norm(total, axis=1)

    def object_box(self, rectifier: Rectifier, margin_px: int = 3, *, pair: int = 0) -> Box | None:
        """The foam's bounding box in the rectified left view of pair `pair` now: what a user would draw
        on the first frame (None without foam or cameras, or with the foam out of the view: an object
        that rolled off the palm)."""
        if self.foam is None or self.stereo is None:
            return None
        from twin.sim.cameras import camera_pose_cv

        m, d = self.world.model, self.world.data
        mujoco.mj_forward(m, d)  # vertex positions of a world not stepped yet; time does not move
        vertices = np.asarray(d.flexvert_xpos, dtype=float)
        left_from_world = np.linalg.inv(camera_pose_cv(m, d, self.stereo_pairs[pair].cameras[0]))
        in_left = vertices @ left_from_world[:3, :3].T + left_from_world[:3, 3]
        rect = in_left @ rectifier.rectified_from_left.T
        uvw = np.column_stack([rect, np.ones(len(rect))]) @ rectifier.P1.T
        uv = uvw[:, :2] / uvw[:, 2:]
        (x0, y0), (x1, y1) = uv.min(axis=0) - margin_px, uv.max(axis=0) + margin_px
        w, h = rectifier.image_size
        x0, y0 = max(0, int(x0)), max(0, int(y0))
        box = x0, y0, min(w, int(np.ceil(x1))) - x0, min(h, int(np.ceil(y1))) - y0
        return box if box[2] > 0 and box[3] > 0 else None

    def surface_truth(self, rectifier: Rectifier) -> SurfaceTruth | None:
        """The foam's visible pixels and rendered surface now (twin.sim.surface_truth)."""
        if self.foam is None or self.stereo is None:
            return None
        from twin.sim.surface_truth import SurfaceScorer

        if self._scorer is None or self._scorer.rectifier is not rectifier:
            if self._scorer is not None:
                self._scorer.close()
            self._scorer = SurfaceScorer(self.world.model, self.world.data, rectifier)
        return self._scorer.snapshot()

    def score_surface(
        self, truth: SurfaceTruth | None, points_hand: np.ndarray, pixels: np.ndarray
    ) -> dict | None:
        """Median/p90 distance to the true surface (mm), visible-surface coverage, points off the foam,
        and each point's distance (`point_error_mm`, for the viewer; not a recorded field)."""
        if truth is None:
            return None
        from twin.sim.surface_truth import score_against

        score = score_against(truth, points_hand, pixels)
        return {
            "median_mm": score.median_mm,
            "p90_mm": score.p90_mm,
            "coverage": score.coverage,
            "outside_fraction": score.outside_fraction,
            "visible_px": score.visible_px,
            "point_error_mm": score.point_error_mm,
        }

    def disconnect(self) -> None:
        """Disconnect the devices and free the truth scorer's renderer."""
        super().disconnect()
        if self._scorer is not None:
            self._scorer.close()
            self._scorer = None

    def hand_pose_in_world(self) -> np.ndarray:
        """4x4 pose of the palm body in the world (fixed: the hand is mounted)."""
        m, d = self.world.model, self.world.data
        mujoco.mj_kinematics(m, d)
        palm = m.body(HAND_FRAME_BODY).id
        pose = np.eye(4)
        pose[:3, :3] = d.xmat[palm].reshape(3, 3)
        pose[:3, 3] = d.xpos[palm]
        return pose

    def write_calibration(self, directory: Path) -> dict[str, Path]:
        """The simulated pads' calibration points and fitted look-up table (as a manufacturer's files),
        and the stereo calibration: the file given to the backend, else the twin's ground truth."""
        files = {} if self.tactile is None else self.tactile.sensor.write_files(directory)
        if self.stereo is not None:
            directory.mkdir(parents=True, exist_ok=True)
            path = directory / STEREO_CALIBRATION_FILE
            mujoco.mj_kinematics(self.world.model, self.world.data)  # camera poses before any step
            if self.stereo_calibration_file is not None:
                from twin.vision.calibration import StereoCalibration

                StereoCalibration.load(self.stereo_calibration_file).save(path)
            else:
                self.stereo.calibration().save(path)
            files["stereo_calibration"] = path
            for name, pair in self.named_stereo_pairs()[1:]:  # a further pair: the twin's truth
                key = stereo_calibration_key(1, name)
                pair.calibration().save(directory / f"{key}.json")
                files[key] = directory / f"{key}.json"
        return files

    def scene(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """The MuJoCo model and data, for 3-D logging."""
        return self.world.model, self.world.data

    def diagnostics(self) -> dict[str, Any]:
        """MuJoCo warnings raised so far."""
        return {"mujoco_warnings": self.world.warnings()}

    def metadata(self) -> dict[str, Any]:
        """Scene, object and physics settings of this run."""
        m = self.world.model
        return {
            "backend": self.name,
            "seed": self.seed,
            "mujoco_version": mujoco.__version__,
            "model": str(HAND_XML.name),
            "timestep_s": float(m.opt.timestep),
            "integrator": mujoco.mjtIntegrator(m.opt.integrator).name,
            "object": self.foam.to_json() if self.foam else None,
            "foam_calibration": _calibration(self.foam),
            "hand_config": vars(self.hand.config),
            "tactile_config": vars(self.tactile.config) if self.tactile else None,
            "stereo_config": vars(self.stereo.config) if self.stereo else None,
            "stereo_placements": list(self.stereo_placements) if self.stereo else None,
        }
