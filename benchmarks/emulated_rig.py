"""`twin emulate rig` as its own process for the benchmarks that drive it through the hardware bridge:
started and waited for until it says ready, and always stopped (never left rendering beside the next)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

TWIN = [sys.executable, "-m", "twin.cli"]


def start(rig_file: Path, log: Path, *options: str, cwd: Path | None = None) -> subprocess.Popen:
    """`twin emulate rig` on ptys writing rig_file, with `options` (an object, --no-cameras, a seed); its
    output to `log` (a file: a full pipe never stalls it). Returns once it says ready."""
    with log.open("w") as out:
        proc = subprocess.Popen(
            [
                *TWIN,
                "emulate",
                "rig",
                "--port",
                "pty",
                "--rig-file",
                str(rig_file),
                *options,
                "--duration",
                "600",
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=cwd,
        )
    deadline = time.monotonic() + 180
    while "\nready" not in log.read_text():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"the rig emulator did not start:\n{log.read_text()}")
        time.sleep(0.1)
    return proc


def stop(proc: subprocess.Popen, grace_s: float = 60.0) -> None:
    """Ctrl-C the emulator; kill it (and say so) if it outlives that by `grace_s`: never left rendering
    beside the next benchmark, as one started with Ctrl-C ignored once did for its 600 s."""
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        print(f"the rig emulator outlived its Ctrl-C by {grace_s:g} s and was killed", file=sys.stderr)
