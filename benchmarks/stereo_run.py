"""Real-time factor of runs with the cameras: 30 fps stereo rendering plus reconstruction and fill-in.

Each row is the compress procedure on the default block with every device of the sim (hand, pads,
stereo pair at 30 fps) for `DURATION_S` of sim time, timed from the first step to the closed run
(process start-up excluded, as in the realtime section). *rig*: sampling, reconstruction and fusion,
nothing written; *full recorded run*: + the Arrow streams (JPEG frames, fused cloud and mesh) and
the Rerun .rrd. Rendering at 320x240 directly (the default) and at the native 640x480 then
area-averaging to 320x240 (`--render-native`) are both shown. The machine's cores are shared by
the physics, the renderer (llvmpipe) and the vision worker thread.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from twin.experiments.compress import PHASES, CompressController

from twin.rig import Rig
from twin.session import RRD_NAME
from twin.sim.backend import SimBackend
from twin.sim.foam import DEFAULT_OBJECT, LIBRARY
from twin.vision.pipeline import StereoPipeline
from twin.vision.reconstruct import Rectifier

DURATION_S = 20.0


def _rig(native: bool, duration_s: float) -> tuple[float, dict[str, float]]:
    backend = SimBackend(LIBRARY[DEFAULT_OBJECT], stereo=True, stereo_render_native=native)
    backend.connect()
    try:
        calibration = backend.stereo.calibration()
        pipeline = StereoPipeline(calibration, backend.object_box(Rectifier(calibration)))
        rig = Rig(backend, phases=PHASES, stereo_pipeline=pipeline)
        t0 = time.perf_counter()
        result = rig.run(CompressController(), duration_s)
        return duration_s / (time.perf_counter() - t0), result.samples
    finally:
        backend.disconnect()


def _full_run(native: bool, duration_s: float) -> tuple[float, float, float]:
    import twin.viz.rerun_log  # noqa: F401 - a one-off import, paid at start-up, not per run
    from twin.session import run_experiment

    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "run"
        t0 = time.perf_counter()
        run_experiment(
            backend=SimBackend(LIBRARY[DEFAULT_OBJECT], stereo=True, stereo_render_native=native),
            controller=CompressController(),
            phases=PHASES,
            duration_s=duration_s,
            run_dir=run_dir,
            experiment={"name": "compress-benchmark"},
            argv=["benchmark"],
        )
        rtf = duration_s / (time.perf_counter() - t0)
        size_mb = sum(p.stat().st_size for p in run_dir.rglob("*") if p.is_file()) / 1e6
        return rtf, size_mb / duration_s * 60.0, (run_dir / RRD_NAME).stat().st_size / 1e6


def run(quick: bool = False) -> dict:
    """RTF of the rig and of the full recorded run with cameras, both render modes."""
    duration = 2.0 if quick else DURATION_S
    rows = []
    for native in (False, True):
        rig_rtf, samples = _rig(native, duration)
        full_rtf, mb_per_min, rrd_mb = _full_run(native, duration)
        # the .rrd's growth per minute: a run half as long gives the static part (blueprint, model)
        rrd_per_min = (rrd_mb - _full_run(native, duration / 2)[2]) / (duration / 2) * 60.0
        rows.append(
            {
                "render": "640x480 -> 320x240 (--render-native)" if native else "320x240 (default)",
                "rig_rtf": rig_rtf,
                "full_rtf": full_rtf,
                "stereo_frames": samples.get("stereo", 0),
                "mb_per_min": mb_per_min,
                "rrd_mb_per_min": rrd_per_min,
            }
        )
    return {"duration_s": duration, "object": DEFAULT_OBJECT, "rows": rows}


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    lines = [
        "## Runs with the cameras (target >= 1x real time)",
        "",
        f"Compress on the {results['object']} for {results['duration_s']:g} s of sim time: hand and pads at "
        "30 Hz, the stereo pair rendered at 30 fps, every pair reconstructed and fused with the pads "
        "(`benchmarks/stereo_run.py`). *rig*: nothing written; *full recorded run*: + Arrow streams "
        "(JPEG frames, fused cloud and mesh) and the Rerun .rrd. *.rrd*: its growth per minute of run "
        "(this run against one half as long); the issue that set its size found 79.5 MB per minute.",
        "",
        "| rendering | stereo frames | rig | full recorded run | run size (MB per minute) "
        "| .rrd (MB per minute) |",
        "|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r['render']} | {r['stereo_frames']} | {r['rig_rtf']:.2f}x | {r['full_rtf']:.2f}x "
            f"| {r['mb_per_min']:.0f} | {r['rrd_mb_per_min']:.1f} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
