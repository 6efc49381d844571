"""Cost of one simulated stereo pair (EGL offscreen, CPU): rendering, resizing and noise, per resolution.

The pair renders the default block scene with the stereo rig (twin.sim.cameras), quality shadowsize=0
offsamples=0. Rows: SimStereo.read() rendering directly at 320x240, or at the native 640x480 area-averaged to
320x240 (the default), or delivering 640x480 frames; then both bare renders without resize or
noise. A read() must stay well under the 33 ms frame period to keep up with 30 fps in sim time.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np

from twin.interface.stereo_spec import StereoConfig
from twin.sim.cameras import LEFT_CAMERA, RIGHT_CAMERA, SimStereo, add_stereo_cameras
from twin.sim.foam import get_object
from twin.sim.scene import compile_scene, scene_mjcf
from twin.sim.world import SimWorld


def _timed(fn, repeats: int) -> float:
    """Median milliseconds of fn() after two warm-up calls."""
    fn()
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _render_pair_ms(world: SimWorld, width: int, height: int, repeats: int) -> float:
    """A bare pair of renders at width x height (no resize, no noise)."""
    renderer = mujoco.Renderer(world.model, height=height, width=width)
    try:

        def pair() -> None:
            for camera in (LEFT_CAMERA, RIGHT_CAMERA):
                renderer.update_scene(world.data, camera=camera)
                renderer.render()

        return _timed(pair, repeats)
    finally:
        renderer.close()


def run(quick: bool = False) -> dict:
    """Milliseconds per stereo pair, median over repeats, for each way of producing it."""
    repeats = 10 if quick else 100
    config = StereoConfig()
    root = scene_mjcf(get_object("block"))
    add_stereo_cameras(root, config)
    world = SimWorld(compile_scene(root))
    rows = []
    for label, native, cam_config in (
        ("read(): render 320x240 + noise", False, config),
        ("read(): render 640x480, INTER_AREA to 320x240 + noise (default)", True, config),
        ("read(): render 640x480, INTER_AREA to 320x240, no noise", True, StereoConfig(noise_std=0.0)),
        ("read(): render 640x480 + noise, frames at 640x480", True, StereoConfig(width=640, height=480)),
    ):
        with SimStereo(world, cam_config, np.random.default_rng(0), render_native=native) as cam:
            rows.append({"pipeline": label, "ms_per_pair": _timed(cam.read, repeats)})
    for width, height in ((320, 240), (640, 480)):
        rows.append(
            {
                "pipeline": f"bare render {width}x{height} (both cameras)",
                "ms_per_pair": _render_pair_ms(world, width, height, repeats),
            }
        )
    for r in rows:
        r["pairs_per_s"] = 1e3 / r["ms_per_pair"]
    return {
        "repeats": repeats,
        "cpus": os.cpu_count(),
        "gl": os.environ.get("MUJOCO_GL", ""),
        "rows": rows,
    }


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    lines = [
        "## Simulated stereo pair: render cost",
        "",
        f"Both cameras of the block scene, MUJOCO_GL={results['gl']} on {results['cpus']} CPU cores "
        f"(no GPU), quality shadowsize=0 offsamples=0; median of {results['repeats']} pairs after "
        "warm-up. Frames are delivered at 320x240; 30 fps needs < 33 ms a pair.",
        "",
        "| pipeline | ms per pair | pairs/s |",
        "|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(f"| {r['pipeline']} | {r['ms_per_pair']:.1f} | {r['pairs_per_s']:.0f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
