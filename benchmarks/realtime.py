"""Real-time factor of the twin: physics alone, the rig with hand sensors, and a full recorded run.

Real-time factor = simulated seconds / wall seconds, each row measured on the compress procedure
(close, balance, then compression) so contacts are as they are in a real run.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from twin.experiments.compress import PHASES, CompressController

from twin.rig import Rig
from twin.sim.backend import SimBackend
from twin.sim.foam import DEFAULT_OBJECT, FIDELITIES, LIBRARY


def _physics_only(foam, duration_s: float) -> tuple[float, dict, float]:
    """Replay the compress run's contact state: run the rig once, then time bare world steps and
    full 162-taxel scans in that grasped state."""
    backend = SimBackend(foam)
    backend.connect()
    Rig(backend, phases=PHASES).run(CompressController(), duration_s)
    world = backend.world
    n = int(2.0 / world.timestep_s)
    t0 = time.perf_counter()
    for _ in range(n):
        world.step()
    wall = time.perf_counter() - t0
    scans = 200
    t0 = time.perf_counter()
    for _ in range(scans):
        backend.tactile.read()
    scan_ms = (time.perf_counter() - t0) / scans * 1e3
    return n * world.timestep_s / wall, world.warnings(), scan_ms


def _rig(foam, duration_s: float, tactile: bool = True) -> float:
    backend = SimBackend(foam, tactile=tactile)
    backend.connect()
    t0 = time.perf_counter()
    Rig(backend, phases=PHASES).run(CompressController(), duration_s)
    return duration_s / (time.perf_counter() - t0)


def _full_run(foam, duration_s: float) -> float:
    import twin.viz.rerun_log  # noqa: F401 - a one-off ~2 s import, paid at start-up, not per run
    from twin.session import run_experiment

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        run_experiment(
            backend=SimBackend(foam),
            controller=CompressController(),
            phases=PHASES,
            duration_s=duration_s,
            run_dir=Path(tmp) / "run",
            experiment={"name": "compress-benchmark"},
            argv=["benchmark"],
        )
        return duration_s / (time.perf_counter() - t0)


def run(quick: bool = False) -> dict:
    """RTF rows per library object at each fidelity preset (the default object first)."""
    duration = 3.0 if quick else 10.0
    rows = []
    base = LIBRARY[DEFAULT_OBJECT]
    names = [DEFAULT_OBJECT] + [name for name in LIBRARY if name != DEFAULT_OBJECT]
    cases = [(name, fidelity) for fidelity in FIDELITIES for name in names]
    if quick:
        cases = cases[:1]
    for name, fidelity in cases:
        foam = LIBRARY[name].with_overrides(fidelity=fidelity)
        physics, warnings, scan_ms = _physics_only(foam, duration)
        row = {
            "object": name,
            "fidelity": fidelity,
            "dof": foam.dof,
            "resolution": foam.resolution,
            "physics_rtf": physics,
            "rig_hand_rtf": _rig(foam, duration, tactile=False),
            "rig_rtf": _rig(foam, duration),
            "scan_ms": scan_ms,
            "warnings": warnings,
            "full_run_rtf": _full_run(foam, duration),
        }
        rows.append(row)
    return {
        "duration_s": duration,
        "rows": rows,
        "default_object": DEFAULT_OBJECT,
        "default_fidelity": base.fidelity,
    }


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    lines = [
        "## Real-time factor (simulated s per wall s; the rig with hand + tactile sensors: target >= 3x for "
        "the fast foam, >= 0.5x for the faithful one)",
        "",
        f"Compress procedure, {results['duration_s']:g} s of sim time per row, one process. "
        "*physics*: bare world steps in the grasped state; *rig*: + hand sampling at 30 Hz, latency, "
        "controller (+ the 162-taxel scan at 30 Hz); *full run*: + Arrow recording and the Rerun .rrd "
        "(3-D scene, pads and contacts at 30 Hz), process start-up (imports) excluded. *scan*: one full "
        "tactile scan in the grasped state (target <= 1 ms).",
        "",
        "| object | fidelity | dof | resolution | physics | rig + hand | rig + hand + tactile "
        "| tactile scan | full recorded run | MuJoCo warnings |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results["rows"]:
        full = f"{r['full_run_rtf']:.2f}x" if "full_run_rtf" in r else "-"
        warn = ", ".join(f"{k}: {v}" for k, v in r["warnings"].items()) or "none"
        default = (
            " (default)"
            if (r["object"], r["fidelity"]) == (results["default_object"], results["default_fidelity"])
            else ""
        )
        lines.append(
            f"| {r['object']}{default} | {r['fidelity']} | {r['dof']} | {r['resolution']} "
            f"| {r['physics_rtf']:.2f}x "
            f"| {r['rig_hand_rtf']:.2f}x | {r['rig_rtf']:.2f}x | {r['scan_ms']:.2f} ms | {full} | {warn} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
