"""What a full recorded run costs beyond its physics (issues 19, 40): `twin run compress` per library object.

One run per object, as the CLI makes it (SimBackend built, run_experiment: Arrow recording and the Rerun
.rrd), imports excluded. Physics is the time MuJoCo itself spent in mj_step (MjData.timer[mjTIMER_STEP],
accumulated by MuJoCo at no cost), measured in the same run as the wall time; the ratio wall / physics is
the figure (target <= 1.3). The breakdown times the run's parts by wrapping their entry points for that
run only (a perf_counter pair per call, ~12k calls: < 1 % of the run); nested calls of one part count once.

*Bare replay* (issue 40): the same run's mj_step calls again, in the same process right after it, with a
wall clock: the model and data as they were at its first step, every step's controls, and the clutches'
switches (equality activations and data) at the steps they happened, and nothing else. MuJoCo is
deterministic, so the replay ends in the run's own state (its largest joint difference is reported).
The run's wall over the replay's is the issue's ratio (target <= 1.3); the CLI's whole 10 s run
(`twin run compress`, a fresh process: imports and start-up included) over the same replay, <= 1.6.
"""

from __future__ import annotations

import copy
import functools
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from twin.experiments.compress import PHASES, CompressController

from twin.sim.foam import DEFAULT_OBJECT, LIBRARY

TARGET_RATIO = 1.3
TARGET_CLI_RATIO = 1.6
PARTS = ("start_up", "step_hooks", "sampling", "controller", "recording", "rerun")
"""Wall time outside mj_step, by part: start-up (the scene composed and compiled, the calibration files
written and read), the Python around every physics step (motor slew, clutches, divergence check), the
30 Hz sampling (hand, truth, tactile scan), the procedure, the Arrow recording and the Rerun .rrd. What
is left (the rig's scheduling and delivery: unit conversion, safety checks, commands) is 'other'."""


def _entry_points() -> dict[str, list[tuple[type, str]]]:
    """The methods whose time is each part's (step hooks: SimWorld.step, less mj_step)."""
    from twin import session
    from twin.recording.writer import RunWriter
    from twin.sim.backend import SimBackend
    from twin.sim.hand import SimHand
    from twin.sim.tactile import SimTactile
    from twin.sim.world import SimWorld
    from twin.viz.rerun_log import RunRecording

    rerun = [m for m in vars(RunRecording) if m.startswith("log_")] + ["__init__", "close"]
    return {
        "start_up": [
            (SimBackend, "__init__"),
            (SimBackend, "write_calibration"),
            (session, "_load_run_files"),
        ],
        "step_hooks": [(SimWorld, "step")],
        "sampling": [(SimHand, "read"), (SimBackend, "ground_truth"), (SimTactile, "read")],
        "controller": [(CompressController, "__call__")],
        "recording": [
            (RunWriter, m) for m in ("__init__", "add_stream", "append", "update_metadata", "warn", "close")
        ],
        "rerun": [(RunRecording, m) for m in rerun],
    }


@contextmanager
def _timed(totals: dict[str, float]):
    """Wrap every entry point (a method, or a module's function) so that its wall time adds to its part
    (outermost call only)."""
    depth = dict.fromkeys(totals, 0)
    saved = []

    def wrap(part: str, fn: Callable) -> Callable:
        @functools.wraps(fn)
        def timed(*args: Any, **kwargs: Any) -> Any:
            depth[part] += 1
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                depth[part] -= 1
                if depth[part] == 0:
                    totals[part] += time.perf_counter() - t0

        return timed

    for part, methods in _entry_points().items():
        for cls, name in methods:
            saved.append((cls, name, vars(cls)[name]))
            setattr(cls, name, wrap(part, vars(cls)[name]))
    try:
        yield
    finally:
        for cls, name, fn in saved:
            setattr(cls, name, fn)


@contextmanager
def _steps_recorded(steps: dict[str, Any]):
    """Record what a bare replay needs: the model and data at the first mj_step, each step's controls, and
    the clutches' switches (twin.sim.clutch: equality activations and data) with the step they precede."""
    from twin.sim.clutch import Clutches

    real_step = mujoco.mj_step
    ctrls: list[np.ndarray] = []
    switches: list[tuple[int, np.ndarray, np.ndarray]] = []
    steps.update(ctrls=ctrls, switches=switches)

    def step(model: mujoco.MjModel, data: mujoco.MjData) -> None:
        if not ctrls:
            steps.update(model=copy.deepcopy(model), data=copy.copy(data))
        ctrls.append(data.ctrl.copy())
        real_step(model, data)
        steps["last"] = (model, data)

    def switched(fn: Callable) -> Callable:
        @functools.wraps(fn)
        def wrapper(self: Clutches, finger: Any, data: mujoco.MjData) -> None:
            fn(self, finger, data)
            switches.append((len(ctrls), data.eq_active.copy(), self.model.eq_data.copy()))

        return wrapper

    saved = {name: vars(Clutches)[name] for name in ("_break_away", "_couple")}
    mujoco.mj_step = step
    for name, fn in saved.items():
        setattr(Clutches, name, switched(fn))
    try:
        yield
    finally:
        mujoco.mj_step = real_step
        for name, fn in saved.items():
            setattr(Clutches, name, fn)


def bare_replay(steps: dict[str, Any]) -> tuple[float, float]:
    """The recorded mj_step calls again, timed with a wall clock: seconds, and the largest |qpos| difference
    from where the run ended (0 when the replay is the run's physics step for step)."""
    model, data = steps["model"], steps["data"]
    pending = list(steps["switches"])
    t0 = time.perf_counter()
    for k, ctrl in enumerate(steps["ctrls"]):
        while pending and pending[0][0] == k:
            _, active, eq_data = pending.pop(0)
            data.eq_active[:] = active
            model.eq_data[:] = eq_data
        data.ctrl[:] = ctrl
        mujoco.mj_step(model, data)
    wall_s = time.perf_counter() - t0
    return wall_s, float(np.max(np.abs(data.qpos - steps["last"][1].qpos)))


def cli_wall_s(object_name: str, duration_s: float, fidelity: str) -> float:
    """`twin run compress` as a user starts it: a fresh process, imports and start-up included."""
    with tempfile.TemporaryDirectory() as tmp:
        argv = [sys.executable, "-m", "twin.cli", "run", "compress", "--object", object_name, "--fidelity"]
        argv += [fidelity, "--duration", f"{duration_s:g}", "--out", str(Path(tmp) / "run"), "--no-progress"]
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, capture_output=True)
        return time.perf_counter() - t0


def measure(object_name: str, duration_s: float, fidelity: str = "fast") -> dict:
    """One full recorded run of the compress procedure: wall, mj_step time and the breakdown (s)."""
    import twin.viz.rerun_log  # noqa: F401 - imports excluded (a one-off ~2 s, paid at start-up)
    from twin.session import run_experiment
    from twin.sim.backend import SimBackend

    totals = dict.fromkeys(PARTS, 0.0)
    steps: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp, _timed(totals), _steps_recorded(steps):
        t0 = time.perf_counter()
        backend = SimBackend(LIBRARY[object_name].with_overrides(fidelity=fidelity))
        run_experiment(
            backend=backend,
            controller=CompressController(),
            phases=PHASES,
            duration_s=duration_s,
            run_dir=Path(tmp) / "run",
            experiment={"name": "compress-benchmark"},
            argv=["benchmark"],
        )
        wall_s = time.perf_counter() - t0
    timer = backend.world.data.timer[mujoco.mjtTimer.mjTIMER_STEP]
    physics_s = float(timer.duration)
    totals["step_hooks"] -= physics_s  # SimWorld.step's time beyond mj_step itself
    totals["other"] = wall_s - physics_s - sum(totals[p] for p in PARTS)
    replay_s, replay_error = bare_replay(steps)
    cli_s = cli_wall_s(object_name, duration_s, fidelity)
    return {
        "replay_s": replay_s,
        "replay_max_qpos_error": replay_error,
        "run_over_replay": wall_s / replay_s,
        "cli_s": cli_s,
        "cli_over_replay": cli_s / replay_s,
        "object": object_name,
        "fidelity": fidelity,
        "steps": int(timer.number),
        "physics_s": physics_s,
        "wall_s": wall_s,
        "ratio": wall_s / physics_s,
        "rtf": duration_s / wall_s,
        "parts_s": totals,
    }


def run(quick: bool = False) -> dict:
    """The default object first, then every other library object, one full run each, at each fidelity."""
    duration = 3.0 if quick else 10.0
    names = [DEFAULT_OBJECT] + [n for n in LIBRARY if n != DEFAULT_OBJECT]
    if quick:
        names = names[:1]
    load, cores = os.getloadavg()[0], os.cpu_count()
    rows = [measure(n, duration, fidelity) for fidelity in ("fast", "faithful") for n in names]
    return {"duration_s": duration, "rows": rows, "load": load, "cores": cores}


def to_markdown(results: dict) -> str:
    """The run_overhead section of BENCHMARKS.md."""
    parts = (*PARTS, "other")
    lines = [
        f"## What a recorded run costs beyond its physics (target: wall <= {TARGET_RATIO:g}x mj_step)",
        "",
        f"`twin run compress`, {results['duration_s']:g} s of sim time per object, one process, imports "
        "excluded (model compile and run files included). *physics*: MuJoCo's own mj_step time "
        "(MjData.timer) and *wall*: the whole run, both from the same run. The breakdown is the wall "
        "time outside mj_step, as a fraction of the physics: *start up* (scene composed and compiled, "
        "calibration files written and read), *step hooks* (motor slew, clutches, divergence check: Python "
        "around each 2 ms step), *sampling* (hand, truth and the 162-taxel scan at 30 Hz), *controller*, "
        "*recording* (Arrow), *rerun* (3-D scene, pads, contacts and plots at 30 Hz), *other* (the rig's "
        "scheduling and delivery: unit conversion, safety checks, commands).",
        "",
        "| object | fidelity | physics | wall | **wall / physics** | real-time factor | "
        + " | ".join(p.replace("_", " ") for p in parts)
        + " | bare replay | **run / replay** | CLI run | **CLI / replay** |",
        "| --- | --- | --- | --- | --- | --- | "
        + " | ".join("---" for _ in parts)
        + " | --- | --- | --- | --- |",
    ]
    for r in results["rows"]:
        is_default = (r["object"], r.get("fidelity")) == (DEFAULT_OBJECT, LIBRARY[DEFAULT_OBJECT].fidelity)
        default = " (default)" if is_default else ""
        shares = " | ".join(f"{r['parts_s'][p] / r['physics_s']:.2f}" for p in parts)
        lines.append(
            f"| {r['object']}{default} | {r.get('fidelity', 'fast')} | {r['physics_s']:.2f} s | "
            f"{r['wall_s']:.2f} s | "
            f"**{r['ratio']:.2f}x** | {r['rtf']:.2f}x | {shares} | {r['replay_s']:.2f} s | "
            f"**{r['run_over_replay']:.2f}x** | {r['cli_s']:.2f} s | **{r['cli_over_replay']:.2f}x** |"
        )
    worst = max(r["replay_max_qpos_error"] for r in results["rows"])
    lines += [
        "",
        f"*bare replay*: the run's own mj_step calls again with its controls and clutch switches, wall "
        f"clock, same process (largest joint difference from the run's end over every row: {worst:.1e}); "
        f"*CLI run*: `twin run compress` in a fresh process, start-up included (targets: run / replay <= "
        f"{TARGET_RATIO:g}x, CLI / replay <= {TARGET_CLI_RATIO:g}x). The machine's 1-minute load average "
        f"when this started: {results.get('load', float('nan')):.1f} on {results.get('cores', 0)} cores.",
    ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
