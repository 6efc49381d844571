"""Frame rate of the stereo reconstruction (twin.vision.reconstruct) at 320x240 on one core, per stage.

Input: noised 320x240 pairs of the simulated Flea2 rig (twin.sim.cameras.SimStereo) looking at the
default block foam, with the rig's ground-truth calibration; the tracker is seeded with the bounding
box of the foam's vertices projected into the first rectified left view. The pairs are rendered before
timing: only the pipeline rectify -> track -> disparity -> cloud -> mesh is timed, with
cv2.setNumThreads(1) (hardware_facts §7: StereoBM 64 disparities, 15 px blocks, ~300 fps on one core).
Rows: the mesh over every kept point, and over every 2nd row and column (mesh_stride=2).
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2
import numpy as np

from twin.interface.stereo_spec import StereoConfig
from twin.sim.cameras import LEFT_CAMERA, SimStereo, add_stereo_cameras, camera_pose_cv
from twin.sim.foam import get_object
from twin.sim.scene import compile_scene, scene_mjcf
from twin.sim.world import SimWorld
from twin.vision.reconstruct import ObjectTracker, Rectifier, default_matcher, reconstruct

STAGES = ("rectify", "track", "disparity", "cloud", "mesh")


def _foam_box(world: SimWorld, rectifier: Rectifier, margin_px: int = 3) -> tuple[int, int, int, int]:
    """Bounding box of the foam's vertices in the rectified left view (what a user would draw)."""
    vertices = np.asarray(world.data.flexvert_xpos, dtype=float)
    left_from_world = np.linalg.inv(camera_pose_cv(world.model, world.data, LEFT_CAMERA))
    in_rect = (
        vertices @ left_from_world[:3, :3].T + left_from_world[:3, 3]
    ) @ rectifier.rectified_from_left.T
    uvw = np.column_stack([in_rect, np.ones(len(in_rect))]) @ rectifier.P1.T
    uv = uvw[:, :2] / uvw[:, 2:]
    (x0, y0), (x1, y1) = uv.min(axis=0) - margin_px, uv.max(axis=0) + margin_px
    w, h = rectifier.image_size
    x0, y0 = max(0, int(x0)), max(0, int(y0))
    return x0, y0, min(w, int(np.ceil(x1))) - x0, min(h, int(np.ceil(y1))) - y0


def run(quick: bool = False) -> dict:
    """Median ms per stage and frames/s of the whole pipeline, one core."""
    frames = 10 if quick else 200
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        config = StereoConfig()
        root = scene_mjcf(get_object("block"))
        add_stereo_cameras(root, config)
        world = SimWorld(compile_scene(root))
        world.step()
        with SimStereo(world, config, np.random.default_rng(0)) as camera:
            calibration = camera.calibration()
            pairs = [camera.read() for _ in range(min(frames, 20))]
        rectifier = Rectifier(calibration)
        matcher = default_matcher(rectifier)
        box = _foam_box(world, rectifier)
        rows = []
        for stride in (1, 2):
            first_left, _ = rectifier.rectify(pairs[0].left, pairs[0].right)
            tracker = ObjectTracker(first_left, box)
            per_stage = {s: [] for s in STAGES}
            totals, points, triangles = [], [], []
            for i in range(frames + 3):
                pair = pairs[i % len(pairs)]
                t0 = time.perf_counter()
                rec = reconstruct(
                    pair.left, pair.right, rectifier, tracker, matcher=matcher, mesh_stride=stride
                )
                if i < 3:
                    continue  # warm-up
                totals.append(time.perf_counter() - t0)
                for s in STAGES:
                    per_stage[s].append(rec.timings_ms[s])
                points.append(len(rec.points_hand))
                triangles.append(len(rec.triangles))
            total_ms = 1e3 * float(np.median(totals))
            rows.append(
                {
                    "mesh_stride": stride,
                    "stages_ms": {s: float(np.median(v)) for s, v in per_stage.items()},
                    "total_ms": total_ms,
                    "fps": 1e3 / total_ms,
                    "points": int(np.median(points)),
                    "triangles": int(np.median(triangles)),
                }
            )
    finally:
        cv2.setNumThreads(threads)
    return {
        "frames": frames,
        "size": list(rectifier.image_size),
        "box": list(box),
        "num_disparities": matcher.getNumDisparities(),
        "block_size": matcher.getBlockSize(),
        "rows": rows,
    }


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    w, h = results["size"]
    lines = [
        "## Stereo reconstruction pipeline (one core)",
        "",
        f"twin.vision.reconstruct on simulated {w}x{h} pairs of the block foam (noised), "
        "cv2.setNumThreads(1); "
        f"StereoBM {results['num_disparities']} disparities, {results['block_size']} px blocks; median of "
        f"{results['frames']} frames after warm-up. The paper reports 6-10 frames/s for the whole "
        "reconstruction.",
        "",
        "| mesh | "
        + " | ".join(f"{s} (ms)" for s in STAGES)
        + " | total (ms) | frames/s | points | triangles |",
        "|---|" + "---|" * (len(STAGES) + 4),
    ]
    for r in results["rows"]:
        mesh = "every point" if r["mesh_stride"] == 1 else f"every {r['mesh_stride']}nd row/col"
        stages = " | ".join(f"{r['stages_ms'][s]:.2f}" for s in STAGES)
        lines.append(
            f"| {mesh} | {stages} | {r['total_ms']:.1f} | {r['fps']:.0f} | {r['points']} | {r['triangles']} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
