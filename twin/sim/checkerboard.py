"""Calibration targets for the simulated rig (paper §4.1): the tiny 4x3 checkerboard sitting in the palm,
and a larger OpenCV chessboard on a mocap body for the stereo pair's own calibration.

Palm board: a thin white plate on the palm face with the six black squares of a 4x3 board of
alternating squares as separate thin boxes on top (so the pattern renders exactly, with no texture
filtering). Columns run along the palm's +x, rows along -y (row 0 toward F3, the top of the camera
images); square (row, col) is black when row + col is even. The black-square centres, in the order
`PALM_BOARD_LAYOUT` lists them, are the feature points twin.vision.hand_eye sorts and triangulates.

Chessboard: `CHESSBOARD_SQUARES` = 9 x 6 squares of `CHESSBOARD_SQUARE_M`, i.e. 8 x 5 inner corners
(OpenCV's pattern size), on a white plate with a one-square quiet zone. One dimension even and one
odd makes the board's two ends differ (the square at one corner is black, at the opposite one
white), which is how twin.vision.hand_eye orders the corners the same way in both views.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
from dm_control import mjcf
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from twin.sim.cameras import DEFAULT_PLACEMENT, HAND_BODY, PLACEMENTS, CameraPlacement, placement_axes
from twin.sim.scene import PALM_SURFACE_Z_M, compile_scene, scene_mjcf

PALM_BOARD_SQUARE_M = 0.014
"""Side of a palm-board square: the 56 x 42 mm board (70 x 56 mm plate) fits the 80 x 68 mm palm face;
at the cameras' ~41 cm a square is ~14 px of the processed 320x240 image (~28 px natively)."""
PALM_BOARD_COLS, PALM_BOARD_ROWS = 4, 3
PALM_BOARD_LAYOUT: tuple[tuple[int, int], ...] = ((0, 0), (0, 2), (1, 1), (1, 3), (2, 0), (2, 2))
"""(row, col) of the six black squares, in the order their centres are reported (row-major)."""
PALM_PLATE_THICKNESS_M = 0.001
PALM_SQUARE_THICKNESS_M = 0.00005
PALM_PLATE_MARGIN_M = 0.007
"""White border around the squares, so no black square touches the (darker) palm."""

CHESSBOARD_SQUARES = (9, 6)
"""Squares along the board's x and y: 8 x 5 inner corners."""
CHESSBOARD_PATTERN = (CHESSBOARD_SQUARES[0] - 1, CHESSBOARD_SQUARES[1] - 1)
"""OpenCV pattern size (inner corners per row, per column)."""
CHESSBOARD_SQUARE_M = 0.015
CHESSBOARD_BODY = "calib_chessboard"
PARKED_POS_M = (0.0, 0.0, -5.0)
"""Where the chessboard waits out of every view (below the floor)."""

WHITE = [0.92, 0.92, 0.92, 1.0]
BLACK = [0.03, 0.03, 0.03, 1.0]
CALIBRATION_OFFSAMPLES = 8
"""Offscreen multisampling of the calibration scene. A sensor pixel integrates the light over its area;
the run scene's aliased render (offsamples 0, for speed) puts chessboard corners 0.26 px RMS off their
true projection at 640x480, 8 samples 0.08 px (measured on the chessboard views; ~1.5x the render time)."""
OPEN_HAND = {"f1_spread": np.pi / 2, "f2_spread": np.pi / 2}
"""Joint angles (rad) that keep the fingers off the palm board: spread fully sideways, links straight."""


def palm_board_centres(square_m: float = PALM_BOARD_SQUARE_M) -> NDArray[np.float64]:
    """(6, 3) ground-truth black-square centres (top faces) in the hand (palm) frame, layout order."""
    z = PALM_SURFACE_Z_M + PALM_PLATE_THICKNESS_M + PALM_SQUARE_THICKNESS_M
    return np.array(
        [
            [(c - (PALM_BOARD_COLS - 1) / 2) * square_m, ((PALM_BOARD_ROWS - 1) / 2 - r) * square_m, z]
            for r, c in PALM_BOARD_LAYOUT
        ]
    )


def _matte(root: mjcf.RootElement) -> None:
    """Matte paper: no specular highlight (it would shade the white unevenly)."""
    if root.find("material", "calib_white") is None:
        for name, rgba in (("calib_white", WHITE), ("calib_black", BLACK)):
            root.asset.add("material", name=name, rgba=rgba, specular=0.0, shininess=0.0, reflectance=0.0)


def add_palm_board(root: mjcf.RootElement, square_m: float = PALM_BOARD_SQUARE_M) -> None:
    """Put the 4x3 board on the palm face (visual geoms of the palm body: nothing collides with it)."""
    _matte(root)
    palm = root.find("body", HAND_BODY)
    for site in palm.find_all("site", immediate_children_only=True):
        site.rgba = [0.0, 0.0, 0.0, 0.0]  # the palm_center marker would show through the board
    half_w = PALM_BOARD_COLS * square_m / 2 + PALM_PLATE_MARGIN_M
    half_h = PALM_BOARD_ROWS * square_m / 2 + PALM_PLATE_MARGIN_M
    common = {"contype": 0, "conaffinity": 0, "group": 1, "density": 0}
    palm.add(
        "geom",
        name="palm_board_plate",
        type="box",
        size=[half_w, half_h, PALM_PLATE_THICKNESS_M / 2],
        pos=[0.0, 0.0, PALM_SURFACE_Z_M + PALM_PLATE_THICKNESS_M / 2],
        material="calib_white",
        **common,
    )
    for i, (x, y, z) in enumerate(palm_board_centres(square_m)):
        palm.add(
            "geom",
            name=f"palm_board_black_{i}",
            type="box",
            size=[square_m / 2, square_m / 2, PALM_SQUARE_THICKNESS_M / 2],
            pos=[x, y, z - PALM_SQUARE_THICKNESS_M / 2],
            material="calib_black",
            **common,
        )


def chessboard_object_points(
    pattern: tuple[int, int] = CHESSBOARD_PATTERN, square_m: float = CHESSBOARD_SQUARE_M
) -> NDArray[np.float32]:
    """(N, 3) inner corners in the board frame, OpenCV order (along a row first), z = 0."""
    cols, rows = pattern
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_m
    return np.column_stack([grid, np.zeros(len(grid))]).astype(np.float32)


def add_chessboard(
    root: mjcf.RootElement,
    squares: tuple[int, int] = CHESSBOARD_SQUARES,
    square_m: float = CHESSBOARD_SQUARE_M,
) -> None:
    """A mocap chessboard (parked out of view): white plate, black square boxes; board frame at its
    first inner corner, x along the first row of corners, z out of the printed face."""
    _matte(root)
    nx, ny = squares
    body = root.worldbody.add("body", name=CHESSBOARD_BODY, mocap="true", pos=list(PARKED_POS_M))
    common = {"contype": 0, "conaffinity": 0, "group": 1, "density": 0}
    # Square (i, j) spans [(i-1) s, i s] x [(j-1) s, j s]: inner corner (0, 0) at the origin.
    cx, cy = (nx / 2 - 1) * square_m, (ny / 2 - 1) * square_m
    body.add(
        "geom",
        name="chessboard_plate",
        type="box",
        size=[(nx / 2 + 1) * square_m, (ny / 2 + 1) * square_m, 0.001],
        pos=[cx, cy, -0.001],
        material="calib_white",
        **common,
    )
    for i in range(nx):
        for j in range(ny):
            if (i + j) % 2 == 0:
                body.add(
                    "geom",
                    name=f"chessboard_black_{i}_{j}",
                    type="box",
                    size=[square_m / 2, square_m / 2, 0.000025],
                    pos=[(i - 0.5) * square_m, (j - 0.5) * square_m, 0.000025],
                    material="calib_black",
                    **common,
                )


def calibration_scene(
    *,
    palm_board: bool = True,
    chessboard: bool = True,
    offsamples: int = CALIBRATION_OFFSAMPLES,
    placement: CameraPlacement | None = None,
) -> mujoco.MjModel:
    """The hand (no foam) with the stereo pair at `placement` (None: the default), the palm board and
    the mocap chessboard, rendered with `offsamples` multisampling."""
    root = scene_mjcf(None, cameras=True, camera_placement=placement)
    root.visual.quality.offsamples = offsamples
    if palm_board:
        add_palm_board(root)
    if chessboard:
        add_chessboard(root)
    return compile_scene(root)


def open_hand(model: mujoco.MjModel, data: mujoco.MjData, angles: dict[str, float] | None = None) -> None:
    """Pose the fingers kinematically (no physics step): OPEN_HAND unless `angles` are given."""
    for name in ("f1_inner", "f2_inner", "f3_inner", "f1_outer", "f2_outer", "f3_outer"):
        data.qpos[model.joint(name).qposadr[0]] = 0.0
    for name, value in (OPEN_HAND if angles is None else angles).items():
        data.qpos[model.joint(name).qposadr[0]] = value
    mujoco.mj_forward(model, data)


def place_chessboard(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    pos_m: Sequence[float] = PARKED_POS_M,
    rotation: Rotation | None = None,
) -> None:
    """Move the mocap chessboard (its first inner corner to `pos_m`, world frame) and update."""
    mocap = model.body(CHESSBOARD_BODY).mocapid[0]
    data.mocap_pos[mocap] = pos_m
    quat = (rotation or Rotation.identity()).as_quat()  # x, y, z, w
    data.mocap_quat[mocap] = [quat[3], quat[0], quat[1], quat[2]]
    mujoco.mj_forward(model, data)


def random_chessboard_poses(
    count: int,
    rng: np.random.Generator,
    *,
    placement: CameraPlacement | None = None,
    lift_m: float = 0.06,
    spread_m: float = 0.03,
    max_tilt_deg: float = 30.0,
    max_spin_deg: float = 20.0,
    squares: tuple[int, int] = CHESSBOARD_SQUARES,
    square_m: float = CHESSBOARD_SQUARE_M,
) -> list[tuple[NDArray[np.float64], Rotation]]:
    """`count` poses (first-corner position, rotation) of the chessboard held up to the cameras of
    `placement` (default: the scene's): its centre within `spread_m` of the point `lift_m` from the
    cameras' target toward them, facing them (face up for the top view, turned toward the pair for a
    lateral one), tilted up to `max_tilt_deg` about a random axis in its plane and turned up to
    `max_spin_deg` about its normal; the board stays in both views."""
    p = placement or PLACEMENTS[DEFAULT_PLACEMENT]
    right, up, toward = placement_axes(p)
    centre_m = np.asarray(p.target_m, dtype=float) + lift_m * toward
    facing = Rotation.from_matrix(np.column_stack([right, up, toward]))  # board x right, z at the pair
    half = np.array([(squares[0] / 2 - 1) * square_m, (squares[1] / 2 - 1) * square_m, 0.0])
    poses = []
    for _ in range(count):
        spin = Rotation.from_rotvec([0.0, 0.0, np.radians(rng.uniform(-max_spin_deg, max_spin_deg))])
        axis_angle = rng.uniform(0, 2 * np.pi)
        tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform())
        tilt_rot = Rotation.from_rotvec(tilt * np.array([np.cos(axis_angle), np.sin(axis_angle), 0.0]))
        rotation = facing * tilt_rot * spin
        centre = centre_m + facing.apply(rng.uniform(-spread_m, spread_m, 3) * [1.0, 1.0, 0.7])
        poses.append((centre - rotation.apply(half), rotation))
    return poses
