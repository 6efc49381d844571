"""The vision side of a run, backend-free: each stereo pair -> reconstruction -> tactile fill-in -> record.

`StereoPipeline` keeps what lasts between frames: the rectification maps, the colour tracker learnt
from the bounding box on the first frame, the block matcher, the hand's kinematics and clutch state
(from every hand reading) and the latest tactile pressures (from every scan). `process` turns one
pair into a `SurfaceFrame`: the fused cloud and mesh the run stores, with both images JPEG-encoded
so a run can be reprocessed later.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import cv2
import mujoco
import numpy as np
from numpy.typing import NDArray

from twin.interface.devices import HandReading, StereoFrame
from twin.interface.errors import ConfigError
from twin.kinematics import HAND_FRAME_BODY, ClutchObserver, HandKinematics
from twin.recording import RAGGED, FieldSpec, StreamSpec
from twin.units import spread_counts_to_rad
from twin.vision.calibration import StereoCalibration
from twin.vision.fusion import FusedSurface, fuse, pressed_taxels
from twin.vision.occlusion import box_corners, hidden_by_boxes
from twin.vision.reconstruct import (
    Box,
    HandRegion,
    ObjectTracker,
    Reconstruction,
    Rectifier,
    default_matcher,
    reconstruct,
)

MATCHER = "sgbm"
"""The run's matcher: semi-global matching with the left-right check (reconstruct.make_sgbm_matcher).
On the paper's lateral view, 10 s compress per library foam, truth-scored (benchmarks/stereo_pipeline.py):
StereoBM (9 px blocks) left 41-54 % of the visible foam without a point and no frame met both targets;
SGBM covers 66-97 % at a 0.3-0.7 mm median, every frame within targets."""
BLOCK_SIZE_PX = {"sgbm": 3, "bm": 9}
"""Matching window per matcher: 3 px for SGBM (its paths do the smoothing: 3 px and 5 px score alike,
3 px is faster); 9 px for StereoBM (a big block straddles the fingers' edges and takes their disparity)."""
FINGER_MARGIN_M = 0.0
"""The fingers' boxes grown by this much for the occlusion test (twin.vision.occlusion). On the lateral
view (10 s compress, truth-scored) 1 mm dropped the foam pressed against the pads too: the cylinder's
coverage fell from 66 % to 60 % (43 % of frames within targets, 100 % at 0 mm)."""
HAND_REGION = HandRegion()
"""Where a held object can be (hand frame): points elsewhere are the room seen past the hand."""
TRACKER_BINS = 64
"""Chromaticity histogram bins per axis: 32 put the blue foam (firm_block) and the blue floor behind it
in the same bins on the lateral view (10 000 floor pixels above threshold); 64 separate them (500)."""
FINGER_BODIES = ("f1_", "f2_", "f3_")
"""Bodies of the hand model whose visual geoms make the finger mask (knuckles, links, tips)."""
STAGES = ("rectify", "track", "disparity", "cloud", "fuse")
"""Timed stages of one frame, in `process_ms` order (`fuse` includes the mesh)."""


def stereo_stream_spec(rate_hz: float, name: str = "stereo", placement: str | None = None) -> StreamSpec:
    """A recorded stereo stream: both frames (JPEG) and the fused surface in the hand frame (`name`:
    twin.interface.backend.stereo_stream_name; `placement`: where the pair stands, if known)."""
    where = "" if placement is None else f" at {placement}"
    return StreamSpec(
        name=name,
        rate_hz=rate_hz,
        description=f"Flea2 pair{where} (JPEG, as delivered) and the fused surface (paper §4.2 + §5), "
        "hand frame",
        fields={
            "left_jpeg": FieldSpec(
                unit="byte",
                shape=(RAGGED,),
                dtype="uint8",
                kind="raw",
                description="left frame, JPEG file bytes",
            ),
            "right_jpeg": FieldSpec(
                unit="byte",
                shape=(RAGGED,),
                dtype="uint8",
                kind="raw",
                description="right frame, JPEG file bytes",
            ),
            "points_m": FieldSpec(
                unit="m", shape=(RAGGED, 3), dtype="float32", description="fused cloud, hand frame"
            ),
            "point_source": FieldSpec(
                unit="1", shape=(RAGGED,), dtype="uint8", kind="status", description="0 vision, 1 tactile"
            ),
            "triangles": FieldSpec(
                unit="1", shape=(RAGGED, 3), dtype="int32", description="fused mesh, indices into points_m"
            ),
            "vision_points": FieldSpec(
                unit="1", dtype="int32", kind="status", description="reconstructed points before thinning"
            ),
            "box": FieldSpec(
                unit="px", shape=(4,), dtype="int32", kind="status", description="tracker window x, y, w, h"
            ),
            "process_ms": FieldSpec(
                unit="ms", shape=(len(STAGES),), dtype="float32", kind="status", description=", ".join(STAGES)
            ),
        },
    )


@dataclass(frozen=True)
class HandSnapshot:
    """What the hand tells the vision about one frame, taken when the frame is delivered (so that the
    frame may be processed on a worker while the hand moves on): the pressed taxels and the fingers."""

    tactile_points_hand: NDArray[np.float64]
    """(k, 3) centres of the pressed taxels, hand frame."""
    finger_corners_hand: NDArray[np.float64] | None
    """(G, 8, 3) corners of the fingers' visual boxes (cylinders boxed), hand frame; None before any
    hand reading."""


@dataclass
class SurfaceFrame:
    """One processed pair: the reconstruction, the tactile points and the fused surface."""

    t_s: float
    reconstruction: Reconstruction
    tactile_points_hand: NDArray[np.float64]
    fused: FusedSurface
    process_ms: dict[str, float]
    left_jpeg: NDArray[np.uint8]
    right_jpeg: NDArray[np.uint8]
    """Both frames as delivered, JPEG-encoded (what the run keeps of them)."""

    def record(self) -> dict:
        """The stereo stream's row."""
        r = self.reconstruction
        return {
            "left_jpeg": self.left_jpeg,
            "right_jpeg": self.right_jpeg,
            "points_m": self.fused.points_hand,
            "point_source": self.fused.source,
            "triangles": self.fused.triangles,
            "vision_points": len(r.points_hand),
            "box": np.asarray(r.box if r.box is not None else (0, 0, 0, 0), dtype=np.int32),
            "process_ms": np.array([self.process_ms.get(s, np.nan) for s in STAGES], dtype=np.float32),
        }


def encode_jpeg(rgb: NDArray[np.uint8], quality: int) -> NDArray[np.uint8]:
    """An RGB frame as JPEG bytes (what the recording keeps of each camera frame)."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.reshape(-1)


def decode_jpeg(data: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The RGB frame back from its recorded JPEG bytes."""
    bgr = cv2.imdecode(np.asarray(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError("not a JPEG image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def parse_box(text: str) -> Box:
    """'x,y,w,h' (pixels of the rectified left view) -> a Box; ConfigError on anything else."""
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 4:
        raise ConfigError(f"--bbox {text!r}: expected x,y,w,h in pixels, e.g. 120,80,70,90")
    if values[2] <= 0 or values[3] <= 0:
        raise ConfigError(f"--bbox {text!r}: the bounding box is empty (width and height must be > 0)")
    return values[0], values[1], values[2], values[3]


class StereoPipeline:
    """Reconstruction + tactile fill-in of every stereo pair of a run (sim or hardware alike)."""

    def __init__(
        self,
        calibration: StereoCalibration,
        box: Box,
        *,
        mesh_stride: int = 2,
        jpeg_quality: int = 90,
        matcher: str = MATCHER,
        block_size: int | None = None,
        erode_px: int = 0,
        region: HandRegion | None = HAND_REGION,
        finger_mask: bool = True,
    ) -> None:
        if mesh_stride < 1:
            raise ConfigError(f"mesh_stride must be >= 1, got {mesh_stride}")
        if not 1 <= jpeg_quality <= 100:
            raise ConfigError(f"jpeg_quality must be in 1-100, got {jpeg_quality}")
        self.calibration = calibration
        self.rectifier = Rectifier(calibration)
        width, height = self.rectifier.image_size
        x, y, w, h = box
        if w <= 0 or h <= 0:
            raise ConfigError(f"bounding box {box} is empty (width and height must be > 0)")
        if x < 0 or y < 0 or x + w > width or y + h > height:
            raise ConfigError(f"bounding box {box} (x, y, w, h) is not inside the {width}x{height} image")
        self.box = box
        self.mesh_stride = mesh_stride
        self.erode_px = erode_px
        self.jpeg_quality = jpeg_quality
        if matcher not in BLOCK_SIZE_PX:
            raise ConfigError(f"matcher {matcher!r}: expected one of {', '.join(BLOCK_SIZE_PX)}")
        self.matcher = default_matcher(
            self.rectifier, block_size=block_size or BLOCK_SIZE_PX[matcher], kind=matcher
        )
        self.region = region
        """Where the object can be (hand frame); points elsewhere are dropped. None: anywhere."""
        self.finger_mask = finger_mask
        """Whether pixels the fingers cover (from the hand's kinematics) are kept out of the object."""
        self.tracker: ObjectTracker | None = None
        self.kinematics = HandKinematics()
        self.clutch = ClutchObserver()
        self._pressure_kpa: NDArray[np.float64] | None = None
        self.image_from_hand = self.rectifier.P1 @ np.linalg.inv(self.rectifier.hand_from_rectified)
        """3x4: hand-frame points -> rectified left pixels."""
        self._left_eye_hand = self.rectifier.hand_from_rectified[:3, 3]
        """The left camera's centre, hand frame (the origin of the rectified left frame)."""
        m = self.kinematics.model
        self._finger_geoms = [
            g
            for g in range(m.ngeom)
            if m.geom_group[g] == 2
            and int(m.geom_type[g]) in (int(mujoco.mjtGeom.mjGEOM_BOX), int(mujoco.mjtGeom.mjGEOM_CYLINDER))
            and m.body(m.geom_bodyid[g]).name.startswith(FINGER_BODIES)
        ]

    def observe_hand(self, reading: HandReading) -> None:
        """Follow the hand's pose (link angles through the clutch observer)."""
        links = self.clutch.update(reading.position_counts, reading.strain_counts)
        self.kinematics.set_angles(links, float(spread_counts_to_rad(reading.position_counts[3])))

    def observe_tactile(self, pressure_kpa: NDArray[np.float64]) -> None:
        """Keep the latest scan's pressures (eq. 5) for the next frame's fill-in."""
        self._pressure_kpa = np.asarray(pressure_kpa, dtype=np.float64)

    def tactile_points(self) -> NDArray[np.float64]:
        """(k, 3) hand-frame centres of the taxels pressed in the latest scan, at the latest hand pose."""
        if self._pressure_kpa is None or not self.kinematics.posed:  # no scan, or no hand pose yet
            return np.zeros((0, 3))
        taxels, _ = self.kinematics.taxels()
        return pressed_taxels(self._pressure_kpa, taxels)

    def finger_corners(self) -> NDArray[np.float64] | None:
        """(G, 8, 3) hand-frame corners of the fingers' visual geoms at the latest hand pose (a
        cylinder by its bounding box); None before any hand reading."""
        if not self.kinematics.posed:
            return None
        m, d = self.kinematics.model, self.kinematics.data
        hand_from_world = np.linalg.inv(_world_pose(d, m.body(HAND_FRAME_BODY).id))
        corners = []
        for g in self._finger_geoms:
            size = m.geom_size[g]
            is_box = int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_BOX)
            half = size if is_box else np.array([size[0], size[0], size[1]])  # a cylinder's box
            world = box_corners(d.geom_xpos[g], d.geom_xmat[g].reshape(3, 3), half)
            corners.append(world @ hand_from_world[:3, :3].T + hand_from_world[:3, 3])
        return np.array(corners)

    def hand_snapshot(self) -> HandSnapshot:
        """The pressed taxels and the fingers now, for the frame being delivered."""
        return HandSnapshot(self.tactile_points(), self.finger_corners() if self.finger_mask else None)

    def _without_fingers(self, recon: Reconstruction, corners_hand: NDArray[np.float64]) -> Reconstruction:
        """The reconstruction less the points a finger hides from the left camera (their disparity is
        the finger's)."""
        hidden = hidden_by_boxes(
            recon.points_hand,
            self._left_eye_hand,
            corners_hand,
            FINGER_MARGIN_M,
            pixels_xy=recon.pixels[:, ::-1],
            image_from_frame=self.image_from_hand,
        )
        if not hidden.any():
            return recon
        keep = ~hidden
        return replace(
            recon, points_hand=recon.points_hand[keep], colors=recon.colors[keep], pixels=recon.pixels[keep]
        )

    def process(self, frame: StereoFrame, hand: HandSnapshot | None = None) -> SurfaceFrame:
        """Reconstruct one pair, keep the fingers out of it and fill it in with the pressed taxels.

        `hand`: the hand when the frame was delivered (`hand_snapshot()`), so that `process` may run
        on a worker thread while the hand and pads move on; None takes it now.
        """
        hand = self.hand_snapshot() if hand is None else hand
        if self.tracker is None:  # the first frame: learn the object's colour inside the box
            left_rect = self.rectifier.remap(frame.left, "left")
            try:
                self.tracker = ObjectTracker(left_rect, self.box, bins=TRACKER_BINS)
            except ValueError as exc:
                raise ConfigError(f"bounding box on the first frame: {exc}") from None
        recon = reconstruct(
            frame.left,
            frame.right,
            self.rectifier,
            self.tracker,
            matcher=self.matcher,
            mesh=False,
            erode_px=self.erode_px,
            region=self.region,
        )
        t0 = time.perf_counter()
        if self.finger_mask and hand.finger_corners_hand is not None:
            recon = self._without_fingers(recon, hand.finger_corners_hand)
        pixels = recon.pixels
        on_grid = (pixels[:, 0] % self.mesh_stride == 0) & (pixels[:, 1] % self.mesh_stride == 0)
        tactile = np.asarray(hand.tactile_points_hand, dtype=np.float64).reshape(-1, 3)
        fused = fuse(
            recon.points_hand[on_grid],
            tactile,
            self.image_from_hand,
            max_edge_m=0.008 * self.mesh_stride,
        )
        timings = dict(recon.timings_ms)
        timings.pop("mesh", None)
        timings["fuse"] = 1e3 * (time.perf_counter() - t0)  # with the finger test
        left_jpeg = encode_jpeg(frame.left, self.jpeg_quality)
        right_jpeg = encode_jpeg(frame.right, self.jpeg_quality)
        return SurfaceFrame(frame.t_s, recon, tactile, fused, timings, left_jpeg, right_jpeg)


def _world_pose(data: mujoco.MjData, body: int) -> NDArray[np.float64]:
    t = np.eye(4)
    t[:3, :3] = data.xmat[body].reshape(3, 3)
    t[:3, 3] = data.xpos[body]
    return t
