"""The hardware loop with cameras: `twin emulate rig` (hand, pads and the stereo pair's MJPEG streams, its
own process) and `twin run compress --backend hardware --rig rig.toml` with and without `--cameras`.

Hand loop rate and stereo rate are the recorded samples over the wall time they span (30 Hz asked). The
run with cameras is compared with the one without, on the same emulator (`twin.compare`): the lag-aligned
finger positions and the mean distance of each finger from its command once the grasp has settled.

Usage: python benchmarks/run_all.py --only camera_bridge
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import emulated_rig

ROOT = Path(__file__).resolve().parents[1]
TWIN = [sys.executable, "-m", "twin.cli"]
SETTLED_S = 3.0
"""Command tracking is averaged after this much of the run (the close and the first contact before)."""


def _run(rig_file: Path, out: Path, duration_s: float, cameras: bool) -> dict:
    """One hardware run; its rates and command tracking."""
    from twin.recording import open_run

    argv = [
        "run",
        "compress",
        "--backend",
        "hardware",
        "--rig",
        str(rig_file),
        "--duration",
        f"{duration_s:g}",
    ]
    argv += ["--out", str(out), "--no-progress", *(["--cameras"] if cameras else [])]
    done = subprocess.run(
        [*TWIN, *argv], capture_output=True, text=True, cwd=ROOT, timeout=10 * duration_s + 120
    )
    if done.returncode != 0:
        raise RuntimeError(f"twin {' '.join(argv)} failed: {done.stderr.strip()}")
    run = open_run(out)
    hand, command = run.stream("hand"), run.stream("command")
    position = hand["position_counts"][:, :3].astype(float)
    cmd = command["position_counts"]
    commanded = np.column_stack([np.interp(hand.t_s, command.t_s, cmd[:, k]) for k in range(3)])
    settled = hand.t_s > SETTLED_S
    row = {
        "hand_samples": len(hand),
        "hand_hz": hand.measured_rate_hz(),
        "tracking_counts": np.abs(commanded - position)[settled].mean(axis=0).round(1).tolist(),
    }
    if cameras:
        stereo = run.stream("stereo")
        row |= {"stereo_frames": len(stereo), "stereo_fps": stereo.measured_rate_hz()}
    return row


def run(quick: bool = False) -> dict:
    """The run without cameras, then with, on one emulated rig (20 s each; 4 s with quick)."""
    from twin.compare import contact_windows_s, position_agreement

    duration_s = 4.0 if quick else 20.0
    with tempfile.TemporaryDirectory(prefix="camera-bridge-") as tmp:
        tmp_path = Path(tmp)
        proc = emulated_rig.start(tmp_path / "rig.toml", tmp_path / "emulator.log", cwd=ROOT)
        try:
            without = _run(tmp_path / "rig.toml", tmp_path / "without", duration_s, cameras=False)
            with_cameras = _run(tmp_path / "rig.toml", tmp_path / "with", duration_s, cameras=True)
            overall = position_agreement(tmp_path / "without", tmp_path / "with")
            windows = contact_windows_s(tmp_path / "without")
            outside = position_agreement(tmp_path / "without", tmp_path / "with", exclude_s=windows)
        finally:
            emulated_rig.stop(proc)
    return {
        "duration_s": duration_s,
        "without": without,
        "with": with_cameras,
        "worst_percent_of_travel": 100 * overall.max_relative_error,
        "worst_outside_grasp_percent": 100 * outside.max_relative_error,
        "lag_s": overall.lag_s,
    }


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    w, c = results["without"], results["with"]

    def tracking(row: dict) -> str:
        return " / ".join(f"{v:g}" for v in row["tracking_counts"])

    return "\n".join(
        [
            "## The hardware loop with cameras (target: hand >= 29.5 Hz, stereo >= 25 fps)",
            "",
            "`twin emulate rig` (its own process: hand and pads on ptys, the stereo pair as MJPEG over "
            f"HTTP, the paper's lateral view) and `twin run compress --backend hardware --rig rig.toml` for "
            f"{results['duration_s']:g} s, without and then with `--cameras` "
            "(`benchmarks/camera_bridge.py`). Tracking: mean |command - position| per finger after "
            f"{SETTLED_S:g} s.",
            "",
            "| run | hand samples | hand loop (Hz) | stereo frames | stereo (fps) "
            "| tracking F1 / F2 / F3 (counts) |",
            "|---|---|---|---|---|---|",
            f"| without cameras | {w['hand_samples']} | {w['hand_hz']:.2f} | - | - | {tracking(w)} |",
            f"| with cameras | {c['hand_samples']} | {c['hand_hz']:.2f} | {c['stereo_frames']} | "
            f"{c['stereo_fps']:.2f} | {tracking(c)} |",
            "",
            f"With against without (`twin.compare`, lag {1e3 * results['lag_s']:+.0f} ms): worst finger "
            f"position error {results['worst_percent_of_travel']:.2f} % of the travel over the run, "
            f"{results['worst_outside_grasp_percent']:.2f} % outside the grasp (first contact to "
            "compression).",
            "",
        ]
    )
