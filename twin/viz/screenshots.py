"""Render runs to PNG with Rerun's own viewer, headless, so the pictures can be looked at in review.

    python -m twin.viz.screenshots RUN_DIR [RUN_DIR ...] --out DIR [--at S]

Each run opens with the blueprint `twin view` gives it (run.rrd, any identify.rrd, the .rbl of its kind),
the time cursor at `--at` seconds (default: the end), and the whole viewer is saved as
DIR/<run>.png. What a view reports it failed to show is printed.

Needs a graphics adapter: a GPU, or Mesa's software Vulkan (lavapipe) on a machine without one:
`apt-get install mesa-vulkan-drivers libvulkan1`, then run with WGPU_BACKEND=vulkan (no X server or
Xvfb: the viewer's --headless mode paints off screen). The "XDG_RUNTIME_DIR" lines it prints are
harmless.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from twin.viz.blueprint import TIMELINE

LOAD_TIMEOUT_S = 30.0
SETTLE_S = 2.0
"""Time the viewer gets after seeking, to load and paint the chunks at the cursor."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _end_s(rrd: Path) -> float:
    """The last time (s) of the run's hand plot: where the screenshot shows the whole run."""
    from twin.viz.rerun_log import read_rrd_scalars

    try:
        t, _ = read_rrd_scalars(rrd, "/plots/hand/position_counts")
    except KeyError:
        return 0.0
    return float(t[-1]) if len(t) else 0.0


def screenshot(run_dir: Path, png: Path, at_s: float | None = None, max_size: int | None = None) -> list[str]:
    """Save the viewer showing a run at at_s (default: its end) to png; what the views report failed."""
    from rerun.experimental import ViewerClient

    from twin.cli.view import view_files

    os.environ.setdefault("WGPU_BACKEND", "vulkan")
    os.environ.setdefault("RERUN_ANALYTICS_ENABLED", "false")
    rerun = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    with tempfile.TemporaryDirectory() as tmp:
        files = view_files(run_dir, Path(tmp) / "blueprint.rbl")
        port = _free_port()
        # The files on the viewer's command line, as `twin view` opens them (ViewerClient.open would
        # register them in a catalog under another application id, and the .rbl would not apply).
        process = subprocess.Popen(
            [rerun, "--headless", "--port", str(port), *files],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # `rerun` is a launcher: the viewer is its child, ended with it
        )
        try:
            viewer = _connected(ViewerClient, f"rerun+http://127.0.0.1:{port}/proxy")
            state = _loaded(viewer)
            t = _end_s(run_dir / "run.rrd") if at_s is None else at_s
            viewer.set_time(TIMELINE, duration=t, play_state="paused", recording=state.active_recording)
            time.sleep(SETTLE_S)
            png.parent.mkdir(parents=True, exist_ok=True)
            png.write_bytes(viewer.take_screenshot(max_size=max_size))
            state = viewer.get_state()
        finally:
            _end(process)
    return [f"{v.name}: {r.severity} {r.summary}" for v in state.views for r in v.reports]


def _end(process: subprocess.Popen) -> None:
    """End the viewer and its launcher (their own process group)."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(process.pid, sig)
            process.wait(timeout=10)
            return
        except ProcessLookupError:
            return
        except subprocess.TimeoutExpired:
            continue


def _connected(client: type, url: str, timeout_s: float = LOAD_TIMEOUT_S) -> object:
    """A ViewerClient on the viewer just started, once it answers."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            viewer = client.connect(url)
            viewer.get_state()
            return viewer
        except ConnectionError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.3)


def _loaded(viewer: object, timeout_s: float = LOAD_TIMEOUT_S) -> object:
    """The viewer's state once nothing is loading and a recording has timelines (or at the timeout)."""
    deadline = time.monotonic() + timeout_s
    while True:
        state = viewer.get_state()
        ready = (
            not state.loading
            and state.active_recording is not None
            and any(r.timelines for r in state.recordings)
        )
        if ready or time.monotonic() > deadline:
            return state
        time.sleep(0.2)


def main(argv: list[str] | None = None) -> int:
    """Screenshot every run given; one line a run."""
    parser = argparse.ArgumentParser(
        prog="python -m twin.viz.screenshots", description=__doc__.split("\n")[0]
    )
    parser.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.add_argument("--at", type=float, default=None, metavar="S", help="time cursor (default: the end)")
    parser.add_argument("--max-size", type=int, default=None, metavar="PX", help="longest side of the PNG")
    args = parser.parse_args(argv)
    for run in args.runs:
        if not (run / "run.rrd").is_file():
            print(f"screenshots: error: no run.rrd in {run}", file=sys.stderr)
            return 2
    for run in args.runs:
        png = args.out / f"{run.resolve().name}.png"
        problems = screenshot(run, png, args.at, args.max_size)
        print(f"{png}" + (f"  (views report: {'; '.join(problems)})" if problems else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
