"""The hardware bridge on a busy machine: fault-free hardware runs against the emulator beside a CPU hog.

`twin emulate hand` serves the BH8-262 on a pty (its own process, as in docs/cli.md), two busy-loop
processes keep every core of a 2-core machine taken, and `twin run compress --backend hardware` runs N
times, each in a fresh process. A run counts as complete when it exits 0 with status "complete"; the
hand loop rate of a run is its recorded samples over the wall time they span (30 Hz asked).

Usage: python benchmarks/bridge_under_load.py [--runs 20] [--duration 10] [--hogs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TWIN = [sys.executable, "-m", "twin.cli"]
HOG = [sys.executable, "-c", "while True: pass"]
RUN_TIMEOUT_S = 120.0
"""A hang guard per run: a 10 s run that takes longer than this counts as incomplete."""


def _start_emulator(rig_file: Path) -> subprocess.Popen:
    """`twin emulate hand` on a pty, writing rig_file; returns once it says ready."""
    proc = subprocess.Popen(
        [*TWIN, "emulate", "hand", "--port", "pty", "--rig-file", str(rig_file)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
    )
    for line in proc.stdout:
        if line.startswith("ready"):
            return proc
    proc.kill()
    raise RuntimeError("the hand emulator did not start")


def _stop(procs: list[subprocess.Popen]) -> None:
    """End the processes this benchmark started (and only those)."""
    for proc in procs:
        if proc.poll() is None:
            proc.terminate()
    for proc in procs:
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _one_run(rig_file: Path, out: Path, duration_s: float) -> dict:
    """One `twin run compress --backend hardware`; what it reported and how fast its hand loop ran."""
    from twin.recording import open_run

    cmd = [*TWIN, "run", "compress", "--backend", "hardware", "--rig", str(rig_file)]
    cmd += ["--duration", f"{duration_s:g}", "--out", str(out), "--no-progress"]
    t0 = time.monotonic()
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, cwd=ROOT)
        rc, stderr = done.returncode, done.stderr
    except subprocess.TimeoutExpired:
        rc, stderr = None, f"no end within {RUN_TIMEOUT_S:g} s"
    row: dict = {"rc": rc, "wall_s": time.monotonic() - t0, "status": None, "samples": 0, "error": None}
    try:
        info = json.loads((out / "run.json").read_text())
        t_s = np.asarray(open_run(out).stream("hand").t_s)
    except (OSError, ValueError, KeyError) as exc:
        last = stderr.strip().splitlines()[-1] if stderr.strip() else f"exit {rc}"
        row["error"] = f"no readable run ({exc}): {last}"
        return row
    row["status"], row["error"] = info.get("status"), info.get("error")
    row["samples"] = len(t_s)
    row["recoveries"] = len(info.get("metadata", {}).get("hand_recoveries", []))
    if len(t_s) > 1:
        row["loop_hz"] = (len(t_s) - 1) / float(t_s[-1] - t_s[0])
        row["worst_gap_ms"] = float(np.diff(t_s).max() * 1e3)
    row["complete"] = rc == 0 and row["status"] == "complete"
    if len(t_s) > 1:
        row["worst_gap_at_s"] = float(t_s[int(np.argmax(np.diff(t_s)))])
    if not row["complete"] and not row["error"]:
        row["error"] = stderr.strip().splitlines()[-1] if stderr.strip() else f"exit {rc}"
    return row


def run(
    quick: bool = False,
    runs: int | None = None,
    duration_s: float | None = None,
    hogs: int = 2,
    keep: Path | None = None,
) -> dict:
    """N fault-free hardware runs against `twin emulate hand` with `hogs` busy processes beside them
    (`keep`: a directory to leave the runs in, else a temporary one)."""
    runs = runs or (2 if quick else 20)
    duration_s = duration_s or (3.0 if quick else 10.0)
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        tmp = keep or Path(scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        emulator = _start_emulator(Path(tmp) / "rig.toml")
        busy = [subprocess.Popen(HOG) for _ in range(hogs)]
        try:
            for i in range(runs):
                row = _one_run(Path(tmp) / "rig.toml", Path(tmp) / f"run{i}", duration_s)
                rows.append(row)
                print(_row_line(i, row), file=sys.stderr, flush=True)
        finally:
            _stop([*busy, emulator])
    return {"runs": runs, "duration_s": duration_s, "hogs": hogs, "cores": os.cpu_count(), "rows": rows}


def _row_line(i: int, row: dict) -> str:
    rate = f"{row['loop_hz']:.2f} Hz" if "loop_hz" in row else "-"
    gap = (
        f"worst gap {row['worst_gap_ms']:.0f} ms at {row['worst_gap_at_s']:.1f} s"
        if "worst_gap_ms" in row
        else ""
    )
    what = "complete" if row.get("complete") else f"NOT complete: {row['error']}"
    recovered = row.get("recoveries", 0)
    return (
        f"run {i + 1}: {what}; {row['samples']} samples, loop {rate}, {gap}, {recovered} recovered cycles, "
        f"wall {row['wall_s']:.1f} s"
    )


def summary(results: dict) -> dict:
    """Complete runs, and the loop rates: each run's and the worst."""
    rows = results["rows"]
    rates = [r["loop_hz"] for r in rows if "loop_hz" in r]
    return {
        "complete": sum(bool(r.get("complete")) for r in rows),
        "total": len(rows),
        "rates_hz": rates,
        "worst_hz": min(rates) if rates else float("nan"),
        "worst_gap_ms": max((r.get("worst_gap_ms", 0.0) for r in rows), default=float("nan")),
        "recoveries": sum(r.get("recoveries", 0) for r in rows),
    }


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    s = summary(results)
    rates = ", ".join(f"{r:.1f}" for r in s["rates_hz"])
    return "\n".join(
        [
            "## The hardware bridge under load",
            "",
            f"{s['total']} fault-free `twin run compress --backend hardware` runs of "
            f"{results['duration_s']:g} s "
            f"against `twin emulate hand` (pty, its own process) with {results['hogs']} busy-loop processes "
            f"beside them on {results['cores']} cores (`python benchmarks/bridge_under_load.py`).",
            "",
            "| complete | hand loop rate, worst (Hz) | worst gap between samples (ms) | recovered cycles |",
            "|---|---|---|---|",
            f"| {s['complete']} / {s['total']} | {s['worst_hz']:.1f} | {s['worst_gap_ms']:.0f} "
            f"| {s['recoveries']} |",
            "",
            f"Hand loop rate of each run (Hz, 30 asked): {rates}.",
            "",
        ]
    )


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main() -> int:
    """Run the benchmark and print complete/total, each run's loop rate and the worst."""
    # SIGTERM, and SIGINT even where a shell started us in the background with it ignored, end the
    # benchmark through its clean-up: the hogs and the emulator go with it.
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    raw = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=raw)
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--hogs", type=int, default=2, help="busy-loop processes beside the runs")
    parser.add_argument("--keep", type=Path, help="leave the runs in this directory")
    args = parser.parse_args()
    if args.runs < 1 or not 0 < args.duration < 3600 or args.hogs < 0:
        parser.error("--runs >= 1, 0 < --duration < 3600, --hogs >= 0")
    results = run(runs=args.runs, duration_s=args.duration, hogs=args.hogs, keep=args.keep)
    s = summary(results)
    print(f"complete: {s['complete']}/{s['total']}")
    print("hand loop rate per run (Hz): " + " ".join(f"{r:.2f}" for r in s["rates_hz"]))
    print(f"worst loop rate: {s['worst_hz']:.2f} Hz; worst gap between samples: {s['worst_gap_ms']:.0f} ms")
    return 0 if s["complete"] == s["total"] else 1


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    sys.exit(main())
