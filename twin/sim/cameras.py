"""The simulated Flea2 stereo pair: two MuJoCo cameras looking at the palm-up hand, rendered offscreen.

Rig (hardware_facts §5, paper §4): the cameras are `BASELINE_M` apart, each toed in by half of
`VERGENCE_DEG` so the optical axes cross at `TARGET_M` (on the palm axis, mid-height of the foam), 386 mm
from each camera. Where the pair stands is data (`CameraPlacement`, named in `PLACEMENTS`): the paper's
lateral view (from the palm's +x side, 30 deg above the palm plane, where the fingers leave the
object in view; DEFAULT_PLACEMENT) or straight down on the palm (`top`, image up = the palm's +y).
Frames are rendered at 320x240 (or at the native 640x480 and area-averaged), then noised.

Conventions for the calibration are OpenCV's (twin.vision.calibration): a MuJoCo camera looks along
its -z with y up, an OpenCV camera along +z with y down, so cv_from_mujoco = diag(1, -1, -1).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import mujoco
import numpy as np
from dm_control import mjcf
from numpy.typing import NDArray

from twin.interface.devices import StereoCamera, StereoFrame
from twin.interface.errors import ConfigError
from twin.interface.specs import DeviceSpec
from twin.interface.stereo_spec import StereoConfig, stereo_device_spec
from twin.rendering import renderer
from twin.sim.world import SimWorld
from twin.vision.calibration import CameraIntrinsics, StereoCalibration

LEFT_CAMERA, RIGHT_CAMERA = "stereo_left", "stereo_right"
BASELINE_M = 0.20
VERGENCE_DEG = 30.0
TARGET_M = (0.0, 0.0, 0.11)
"""Where the optical axes cross (palm frame): the palm centre, at the foam's mid-height."""
HAND_BODY = "palm"
"""The hand frame is the palm body's frame."""
FOAM_NAME = "foam"
"""twin.sim.scene.FOAM_NAME (not imported: scene.py may import this module)."""
RENDER_AHEAD = 3
"""Pairs read_async may have in flight (snapshot buffers); a fourth waits for the oldest."""
NOISE_BANK = 8
"""Pre-drawn noise fields a SimStereo shifts at random per view (see SimStereo._corrupt)."""
CV_FROM_MUJOCO = np.diag([1.0, -1.0, -1.0])
"""Camera axes: OpenCV (x right, y down, z forward) from MuJoCo (x right, y up, looking along -z)."""


@dataclass(frozen=True)
class CameraPlacement:
    """Where the pair looks from, as data (the rig description): the pair's midpoint sits on the ray from
    `target_m` at `azimuth_deg` (from the palm's +x toward +y) and `elevation_deg` (above the palm plane;
    90 = straight down), as far as the baseline and the angle between the axes put the axes' crossing on
    the target; the baseline is horizontal in the image."""

    name: str = "lateral"
    baseline_m: float = BASELINE_M
    vergence_deg: float = VERGENCE_DEG
    """Angle between the two optical axes (each camera toed in by half of it)."""
    target_m: tuple[float, float, float] = TARGET_M
    azimuth_deg: float = 0.0
    elevation_deg: float = 90.0

    def __post_init__(self) -> None:
        where = f"camera placement {self.name!r}"
        if not 0.0 < self.baseline_m <= 2.0:
            raise ValueError(f"{where}: baseline_m {self.baseline_m} is not in (0, 2]")
        if not 0.0 < self.vergence_deg < 120.0:
            raise ValueError(f"{where}: vergence_deg {self.vergence_deg} is not in (0, 120)")
        if not -10.0 <= self.elevation_deg <= 90.0:
            raise ValueError(f"{where}: elevation_deg {self.elevation_deg} is not in [-10, 90]")
        if len(self.target_m) != 3:
            raise ValueError(f"{where}: target_m must be 3 numbers (x, y, z)")


PLACEMENTS: dict[str, CameraPlacement] = {
    "top": CameraPlacement("top", elevation_deg=90.0),
    "lateral": CameraPlacement("lateral", azimuth_deg=0.0, elevation_deg=30.0),
    "opposite": CameraPlacement("opposite", azimuth_deg=180.0, elevation_deg=30.0),
}
"""Named placements: `top` looks straight down on the palm-up hand (image up = the palm's +y, toward
F3); `lateral` is the paper's view (§4, Fig. 1b): from the side where F1/F2 and F3 leave a gap, 30 deg
above the palm plane, so the object shows beside the closing fingers; `opposite` is its mirror through
the palm axis (the palm's -x side, the other gap), the second pair of a rig that sees two opposite faces."""
DEFAULT_PLACEMENT = "lateral"
"""The scene's placement when none is given: the paper's. The study (BENCHMARKS.md, stereo_pipeline)
puts every library foam within the reconstruction's targets from `lateral` against 2 of 5 from the
top. The shape pipeline's contours (twin.vision.contour.to_view_plane) and height maps
(twin.shape.surface) work in the pair's own view frame, from its calibration: any placement."""


def placements_named(given: str | Sequence[str]) -> list[CameraPlacement]:
    """The placements named in `given` (one string `lateral,opposite` or a sequence), each at most once;
    ConfigError in one line otherwise."""
    names = [n.strip() for n in (given.split(",") if isinstance(given, str) else given)]
    unknown = [n for n in names if n not in PLACEMENTS]
    if unknown or not names or len(set(names)) < len(names):
        raise ConfigError(
            f"camera placements {','.join(names) or '(none)'}: name each of {', '.join(PLACEMENTS)} "
            "at most once"
        )
    return [PLACEMENTS[n] for n in names]


def pair_camera_names(pair: int = 0) -> tuple[str, str]:
    """The MuJoCo names of pair `pair`'s left and right cameras: the first pair's are LEFT_CAMERA and
    RIGHT_CAMERA (a one-pair rig as ever), a further pair's carry its index (`stereo1_left`, ...)."""
    if pair == 0:
        return LEFT_CAMERA, RIGHT_CAMERA
    return f"stereo{pair}_left", f"stereo{pair}_right"


def _up_hint(forward: NDArray[np.float64]) -> NDArray[np.float64]:
    """Image up: the palm's +y seen from above, the palm's normal (+z) from the side."""
    return np.array([0.0, 1.0, 0.0]) if abs(forward[2]) > 0.99 else np.array([0.0, 0.0, 1.0])


def placement_axes(
    placement: CameraPlacement | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The pair's image right (along the baseline), image up, and the unit vector from the target
    toward the pair's midpoint, in the palm frame."""
    p = placement or PLACEMENTS[DEFAULT_PLACEMENT]
    az, el = math.radians(p.azimuth_deg), math.radians(p.elevation_deg)
    out = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    right = np.cross(-out, _up_hint(-out))
    right /= np.linalg.norm(right)
    return right, np.cross(out, right), out


def stereo_camera_poses(
    placement: CameraPlacement | None = None, names: tuple[str, str] = (LEFT_CAMERA, RIGHT_CAMERA)
) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Position and MuJoCo xyaxes of each camera of `placement` (default: DEFAULT_PLACEMENT), by
    `names` (left, right)."""
    p = placement or PLACEMENTS[DEFAULT_PLACEMENT]
    target = np.asarray(p.target_m, dtype=float)
    half = math.radians(p.vergence_deg) / 2.0
    distance = 0.5 * p.baseline_m / math.sin(half)  # camera to target along each axis
    mid_distance = 0.5 * p.baseline_m / math.tan(half)
    right, _, out = placement_axes(p)
    up_hint = _up_hint(-out)
    mid = target + mid_distance * out
    poses = {}
    for name, side in ((names[0], -1.0), (names[1], 1.0)):
        pos = mid + side * 0.5 * p.baseline_m * right
        forward = (target - pos) / distance
        x_axis = np.cross(forward, up_hint)  # image right
        x_axis /= np.linalg.norm(x_axis)
        y_axis = np.cross(-forward, x_axis)
        poses[name] = (pos, np.concatenate([x_axis, y_axis]))
    return poses


def add_stereo_cameras(
    root: mjcf.RootElement,
    config: StereoConfig | None = None,
    *,
    placement: CameraPlacement | Sequence[CameraPlacement] | None = None,
    foam_texture: bool = True,
) -> None:
    """Add the Flea2 pair at `placement` to the world body, cheap offscreen rendering, and a porous
    foam texture. A sequence of placements adds one pair at each, named by pair_camera_names."""
    config = config or StereoConfig()
    placements = placement if isinstance(placement, Sequence) else [placement]
    poses: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
    for pair, where in enumerate(placements):
        poses.update(stereo_camera_poses(where, pair_camera_names(pair)))
    for name, (pos, xyaxes) in poses.items():
        root.worldbody.add(
            "camera", name=name, pos=pos.tolist(), xyaxes=xyaxes.tolist(), fovy=config.fovy_deg
        )
    # Shadows and multisampling cost ~20x on a CPU renderer (hardware_facts §7).
    root.visual.quality.shadowsize = 0
    root.visual.quality.offsamples = 0
    glob = root.visual.get_children("global")
    glob.offwidth = max(glob.offwidth or 0, config.native_width)
    glob.offheight = max(glob.offheight or 0, config.native_height)
    if foam_texture:
        add_foam_texture(root)


PORE_TEXELS = 256
"""Texels across the pore texture of a flexcomp primitive, whose texture coordinates MuJoCo spans over
each face: ~0.25 mm a texel on the library's 60-70 mm faces (a processed pixel is ~0.95 mm at the
working distance: f = 405 px at 386 mm)."""
PORE_TEXEL_M = 0.5e-3
"""Texel pitch on the surface of a direct (tetrahedral) flex, whose texture coordinates are computed
here (pore_texcoords). Measured on compress runs with the lateral pair (an egg and a bumpy sphere from
STL, 10 s; the faithful block, 5.5 s), median of the frames' median errors: 0.64 / 0.36 / 0.38 mm at
0.25 mm (the primitives' pitch), the egg's worst frame 1.96 mm; 0.42 / 0.33 / 0.31 mm at 0.5 mm, worst
0.69 mm; 0.75-1 mm gain under 0.05 mm more and lose 1-3 points of coverage."""
DIRECT_PORE_TEXELS = 512
"""Texels across the pore texture of a direct flex: 256 mm at PORE_TEXEL_M. The widest map (4 x the
equal-area radius of pore_texcoords: 267 mm for the largest object the hand takes, a 90 x 90 x 110 mm
block) wraps only at its rim, the bottom, which rests on the palm."""


def add_foam_texture(root: mjcf.RootElement, name: str = FOAM_NAME) -> bool:
    """Give the flexcomp `name` an open-cell look: random dark pores, tinted by its rgba; False if absent.

    The texture is grey-scale (white with grey pores) so the object's own rgba keeps its colour; the
    pores give the stereo matcher (OpenCV's StereoSGBM, twin.vision.pipeline) the surface texture a
    real foam has: at the working distance a pore is ~1 processed pixel and the pattern does not repeat
    across the object.
    MuJoCo gives a flexcomp primitive its texture coordinates; a direct flex (the faithful preset,
    every mesh foam) has none, and MuJoCo draws a flex without them untextured, so they are computed
    here from its rest shape (pore_texcoords).
    """
    foam = root.find("flexcomp", name)
    if foam is None:
        return False
    direct = foam.type == "direct"
    texture = f"{name}_pores"
    if root.find("texture", texture) is None:
        texels = DIRECT_PORE_TEXELS if direct else PORE_TEXELS
        root.asset.add(
            "texture",
            name=texture,
            type="2d",
            builtin="flat",
            mark="random",
            random=0.4,
            rgb1=[1.0, 1.0, 1.0],
            rgb2=[1.0, 1.0, 1.0],
            markrgb=[0.45, 0.45, 0.45],
            width=texels,
            height=texels,
        )
        root.asset.add(
            "material",
            name=texture,
            texture=texture,
            texrepeat=[1.0, 1.0],
            texuniform="true",
            specular=0.05,
            shininess=0.05,
        )
    if direct and foam.texcoord is None and foam.point is not None:
        points = np.asarray(foam.point, dtype=float).reshape(-1, 3)
        tets = np.asarray(foam.element, dtype=int).reshape(-1, 4)
        uv_m = pore_texcoords(points, tets)
        foam.texcoord = (uv_m / (DIRECT_PORE_TEXELS * PORE_TEXEL_M) + 0.5).ravel().tolist()
    if foam.rgba is None:
        foam.rgba = [0.95, 0.75, 0.35, 1.0]  # pale yellow-orange polyurethane
    foam.material = texture
    return True


def boundary_faces(tets: NDArray[np.int_]) -> NDArray[np.int_]:
    """The triangles of a tetrahedral mesh that belong to one tetrahedron only: its surface."""
    faces = tets[:, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]].reshape(-1, 3)
    _, first, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
    return faces[first[counts == 1]]


def pore_texcoords(points_m: NDArray[np.float64], tets: NDArray[np.int_]) -> NDArray[np.float64]:
    """Per-vertex texture coordinates (m, centred on 0) of a tetrahedral solid: Lambert's azimuthal
    equal-area map of the directions from its centre, the pole up (+z).

    MuJoCo takes one texture coordinate per vertex, so the map must be continuous over the surface: a
    seam would smear the texture over the triangles across it. A closed surface cannot be mapped onto
    the plane without a singular point; this one puts it straight down, where the object rests on the
    palm. The radius makes the map's area the surface's, so on a sphere the pores keep their density
    everywhere and are stretched by at most 1.4x above the equator, 2x at 30 deg below it."""
    surface = boundary_faces(tets)
    tri = points_m[surface]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    radius = math.sqrt(area / (4.0 * math.pi))
    d = points_m - 0.5 * (points_m.min(axis=0) + points_m.max(axis=0))
    norm = np.linalg.norm(d, axis=1)
    theta = np.arccos(np.clip(d[:, 2] / np.maximum(norm, 1e-12), -1.0, 1.0))
    phi = np.arctan2(d[:, 1], d[:, 0])
    r = 2.0 * radius * np.sin(theta / 2.0)
    return np.c_[r * np.cos(phi), r * np.sin(phi)]


def _pose(xpos: NDArray[np.float64], xmat: NDArray[np.float64]) -> NDArray[np.float64]:
    t = np.eye(4)
    t[:3, :3] = np.asarray(xmat).reshape(3, 3)
    t[:3, 3] = xpos
    return t


def camera_pose_cv(model: mujoco.MjModel, data: mujoco.MjData, camera: str) -> NDArray[np.float64]:
    """4x4 world pose of `camera` in OpenCV axes (z along the optical axis, y down the image)."""
    cam = model.camera(camera).id
    pose = _pose(data.cam_xpos[cam], data.cam_xmat[cam])
    pose[:3, :3] = pose[:3, :3] @ CV_FROM_MUJOCO.T
    return pose


def camera_intrinsics(model: mujoco.MjModel, camera: str, width: int, height: int) -> CameraIntrinsics:
    """MuJoCo's pinhole as an OpenCV K: f = (H/2)/tan(fovy/2), square pixels, centre (W-1)/2, (H-1)/2.

    MuJoCo's frustum spans the image edges, so pixel i covers [i, i+1] and the optical axis hits
    W/2, H/2 in edge coordinates; OpenCV counts from the first pixel's centre, hence the -0.5.
    """
    cam = model.camera(camera).id
    f = 0.5 * height / math.tan(math.radians(float(model.cam_fovy[cam])) / 2.0)
    k = np.array([[f, 0.0, width / 2.0 - 0.5], [0.0, f, height / 2.0 - 0.5], [0.0, 0.0, 1.0]])
    return CameraIntrinsics(k, np.zeros(5), (width, height))


def ground_truth_calibration(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    config: StereoConfig | None = None,
    *,
    hand_body: str = HAND_BODY,
    cameras: tuple[str, str] = (LEFT_CAMERA, RIGHT_CAMERA),
) -> StereoCalibration:
    """The exact calibration of the simulated pair `cameras` (left, right) at the processed size (what a
    perfect rig would fit)."""
    config = config or StereoConfig()
    left_camera, right_camera = cameras
    world_left = camera_pose_cv(model, data, left_camera)
    world_right = camera_pose_cv(model, data, right_camera)
    right_from_left = np.linalg.inv(world_right) @ world_left
    body = model.body(hand_body).id
    hand_from_left = np.linalg.inv(_pose(data.xpos[body], data.xmat[body])) @ world_left
    return StereoCalibration(
        camera_intrinsics(model, left_camera, config.width, config.height),
        camera_intrinsics(model, right_camera, config.width, config.height),
        right_from_left[:3, :3],
        right_from_left[:3, 3],
        hand_from_left,
        "simulated ground truth",
    )


class SimStereo(StereoCamera):
    """The two MuJoCo cameras of a SimWorld rendered offscreen (EGL), frames at the processed size.

    With `render_native` (default) both views are rendered at the native 640x480 and area-averaged to
    320x240 (anti-aliased like a scaled camera image); otherwise they are rendered at 320x240 directly
    (about 2x cheaper, with aliased edges). The declared noise is added to the delivered frame.
    `cameras`: the pair's (left, right) camera names (pair_camera_names; default the first pair).
    """

    def __init__(
        self,
        world: SimWorld,
        config: StereoConfig,
        rng: np.random.Generator,
        *,
        render_native: bool = True,
        cameras: tuple[str, str] = (LEFT_CAMERA, RIGHT_CAMERA),
    ) -> None:
        super().__init__()
        self.world = world
        self.cameras = cameras
        self.config = config
        self.render_native = render_native
        self._spec = stereo_device_spec(config)
        self._rng = rng
        self._renderer: mujoco.Renderer | None = None
        self._noise: NDArray[np.int16] | None = None
        self._render_thread: ThreadPoolExecutor | None = None
        self._thread_renderer: mujoco.Renderer | None = None
        self._snapshots: list[mujoco.MjData] = []
        self._snapshot_jobs: list[Future | None] = []
        self._next_snapshot = 0
        for name in cameras:
            world.model.camera(name)  # KeyError now rather than at connect() when the rig is missing

    @property
    def spec(self) -> DeviceSpec:
        """Declared rate, latency and channels."""
        return self._spec

    def _connect(self) -> None:
        c = self.config
        w, h = (c.native_width, c.native_height) if self.render_native else (c.width, c.height)
        self._renderer = renderer(self.world.model, height=h, width=w)

    def _disconnect(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._render_thread is not None:
            self._render_thread.submit(self._close_thread_renderer).result()
            self._render_thread.shutdown(wait=True)
            self._render_thread = None

    def read_async(self) -> Future[StereoFrame]:
        """Snapshot the physics state now and render the pair on the camera's render thread, so the
        world steps on while the (CPU) renderer works; the frame is the snapshot's, noised as read()."""
        self._require_connection()
        if self._render_thread is None:
            self._render_thread = ThreadPoolExecutor(1, thread_name_prefix="sim-cameras")
            self._snapshots = [mujoco.MjData(self.world.model) for _ in range(RENDER_AHEAD)]
            self._snapshot_jobs = [None] * RENDER_AHEAD
        k = self._next_snapshot
        self._next_snapshot = (k + 1) % RENDER_AHEAD
        if self._snapshot_jobs[k] is not None:
            self._snapshot_jobs[k].result()  # its last pair is rendered: the buffer may be reused
        snapshot = self._snapshots[k]
        mujoco.mj_copyData(snapshot, self.world.model, self.world.data)
        # The noise is drawn now, in call order, so a seed gives the same frames as read().
        k_left, k_right = self._noise_draw(), self._noise_draw()
        t_s = self.world.time_s
        job = self._render_thread.submit(self._render_snapshot, snapshot, t_s, k_left, k_right)
        self._snapshot_jobs[k] = job
        return job

    def _render_snapshot(
        self, data: mujoco.MjData, t_s: float, k_left: tuple[int, int], k_right: tuple[int, int]
    ) -> StereoFrame:
        if self._thread_renderer is None:  # the GL context lives on this thread
            c = self.config
            w, h = (c.native_width, c.native_height) if self.render_native else (c.width, c.height)
            self._thread_renderer = renderer(self.world.model, height=h, width=w)
        left = self._render_with(self._thread_renderer, data, self.cameras[0])
        right = self._render_with(self._thread_renderer, data, self.cameras[1])
        return StereoFrame(t_s=t_s, left=self._add_noise(left, k_left), right=self._add_noise(right, k_right))

    def _close_thread_renderer(self) -> None:
        if self._thread_renderer is not None:
            self._thread_renderer.close()
            self._thread_renderer = None

    def calibration(self) -> StereoCalibration:
        """The ground-truth calibration of this pair now (the hand frame is the palm body)."""
        return ground_truth_calibration(self.world.model, self.world.data, self.config, cameras=self.cameras)

    def render(self, camera: str) -> NDArray[np.uint8]:
        """One noiseless view at the processed size, from the world's present state."""
        self._require_connection()
        assert self._renderer is not None
        return self._render_with(self._renderer, self.world.data, camera)

    def _render_with(self, renderer: mujoco.Renderer, data: mujoco.MjData, camera: str) -> NDArray[np.uint8]:
        renderer.update_scene(data, camera=camera)
        image = renderer.render()
        c = self.config
        if image.shape[:2] != (c.height, c.width):
            image = cv2.resize(image, (c.width, c.height), interpolation=cv2.INTER_AREA)
        return image

    def _noise_draw(self) -> tuple[int, int]:
        """Which pre-drawn noise field, and by how much it is shifted, for the next view."""
        c = self.config
        if self._noise is None:
            shape = (NOISE_BANK, c.height, c.width, 3)
            fields = self._rng.standard_normal(shape, dtype=np.float32)
            self._noise = np.rint(fields * np.float32(c.noise_std)).astype(np.int16)
        return int(self._rng.integers(NOISE_BANK)), int(self._rng.integers(c.height * c.width * 3))

    def _add_noise(self, image: NDArray[np.uint8], draw: tuple[int, int]) -> NDArray[np.uint8]:
        """Sensor noise: one of NOISE_BANK pre-drawn Gaussian fields, shifted by a random offset.

        Drawing 230k normals per view costs ~2 ms; shifting a pre-drawn field costs ~0.2 ms and is
        still white noise per pixel, independent between the views and across frames for practical
        purposes (NOISE_BANK fields x H*W*3 offsets). Deterministic for the backend's seed.
        """
        if self.config.noise_std <= 0:
            return image
        k, shift = draw
        noise = np.roll(self._noise[k].reshape(-1), shift).reshape(image.shape)
        return np.clip(image.astype(np.int16) + noise, 0, 255).astype(np.uint8)

    def _corrupt(self, image: NDArray[np.uint8]) -> NDArray[np.uint8]:
        if self.config.noise_std <= 0:
            return image
        return self._add_noise(image, self._noise_draw())

    def read_view(self, camera: str) -> NDArray[np.uint8]:
        """One noised view now (what a single camera of the pair delivers)."""
        return self._corrupt(self.render(camera))

    def read(self) -> StereoFrame:
        """Both views of the same physics state (a hardware-triggered pair), noised, at sim time."""
        left, right = self.render(self.cameras[0]), self.render(self.cameras[1])
        return StereoFrame(t_s=self.world.time_s, left=self._corrupt(left), right=self._corrupt(right))
