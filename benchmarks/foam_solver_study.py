"""Solver settings for the volumetric ("faithful") foam: speed, iterations, warnings and physics.

The faithful foam (twin.sim.foam PRESETS) is a tetrahedral flex of ~0.05 g vertices pressed by stiff
contacts (solimp 0.9999). Under MuJoCo's discrete integrator the step solves in the effective metric
M + hD + h^2 K: an inner PCG with a 3x3 block preconditioner (its cap and target are opt.iterations and
opt.tolerance; short of them: mjWARN_INERTIA), inside the CG or Newton constraint solve. Each variant
below changes solver options and/or the foam's vertex armature (added inertia, no weight).

Two measurements per variant:
- *step*: ms per mj_step and solver iterations from one saved grasped state (the compress run driven
  `settle_s`, then qpos/qvel/act/ctrl/mocap/warm start restored before each variant), variants
  interleaved `repeats` times (the machine is shared: medians, and ratios to the baseline measured in
  the same round);
- *rig*: a whole compress Rig.run (hand + tactile) from rest under the variant: real-time factor,
  MuJoCo warnings of the run, and the differences of the hand readings (position_counts, torque_nm)
  and of the total normal contact force on the foam from the baseline run, over `window_s`.

What the study found (MuJoCo 3.17, BENCHMARKS.md for the figures): in the grasp CG needs ~550
iterations to reach 1e-5 (the contacts: ~10 without them), so every capped CG is inexact and the cap
sets the cost (~20 us an iteration) and the jitter of the contact forces. The inner M+K solve needs
> 100 iterations at 1e-5, so a lower cap warns, unless the vertices get armature: it conditions M+K
(and the outer solve: ~310 iterations to converge at 1e-3 kg). The armature only counts after
mj_setConst (dof_M0 caches it). Heavier vertices (density x10 with gravcomp for the same weight), a
smaller or larger timestep, the elliptic cone, ls_tolerance, DIAGEXACT, warm start off, islands or
midphase off gain nothing or lose; Newton converges in ~10 iterations at ~0.7 ms each (1.7x slower);
the dense Jacobian is 2.6x slower; PGS and noslip are refused with a flex under the discrete
integrator (mj_checkDiscrete). Collision is ~0.2 ms of the ~4 ms step.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from twin.experiments.compress import PHASES, CompressController

from twin import units
from twin.interface.devices import HandCommand, HandReading
from twin.rig import Rig
from twin.sim.backend import SimBackend
from twin.sim.foam import LIBRARY, FoamParams
from twin.sim.scene import FOAM_NAME

READINGS = ("position_counts", "torque_nm", "force_n")
STATE = mujoco.mjtState.mjSTATE_INTEGRATION
"""Everything mj_step reads: qpos, qvel, act, ctrl, mocap, eq_active, warm start, time."""


@dataclass(frozen=True)
class Variant:
    """One solver configuration: mjOption fields (None: as the scene sets it) and the foam's armature."""

    label: str
    solver: str = "CG"
    tolerance: float = 1e-5
    iterations: int = 200
    ls_iterations: int | None = None
    ls_tolerance: float | None = None
    cone: str | None = None
    armature_kg: float = 0.0
    """Added to every foam vertex dof (inertia without weight); mj_setConst rebuilds what depends on it."""
    disable: tuple[str, ...] = ()
    """mjDSBL_ flag names without the prefix (e.g. "WARMSTART")."""
    enable: tuple[str, ...] = ()
    """mjENBL_ flag names without the prefix (e.g. "DIAGEXACT")."""


BASELINE = Variant("baseline: CG, tol 1e-5, 200 it")
REFERENCE = Variant("Newton, tol 1e-8, 200 it (converged)", solver="Newton", tolerance=1e-8)
"""The converged solution: how far the baseline itself is from it sizes the tolerance of the others."""
CHOSEN = Variant("CG, 120 it, armature 1e-3 kg", iterations=120, armature_kg=1e-3)
"""The recommendation: no warnings, ~0.65x the baseline's step, the baseline's jitter, and a held grasp
within 0.01 N*m and 1 N of the converged solve (the baseline's whole-run error is larger)."""
STEP_VARIANTS: tuple[Variant, ...] = (
    BASELINE,
    Variant("CG, 150 it", iterations=150),
    Variant("CG, 120 it", iterations=120),
    Variant("CG, 100 it", iterations=100),
    Variant("CG, ls_tolerance 0.1", ls_tolerance=0.1),
    Variant("CG, elliptic cone", cone="ELLIPTIC"),
    Variant("CG, no warm start", disable=("WARMSTART",)),
    Variant("CG, DIAGEXACT", enable=("DIAGEXACT",)),
    Variant("Newton, tol 1e-5", solver="Newton"),
    Variant("Newton, tol 1e-5, 50 it", solver="Newton", iterations=50),
    Variant("CG, armature 1e-4 kg", armature_kg=1e-4),
    Variant("CG, 150 it, armature 1e-4 kg", iterations=150, armature_kg=1e-4),
    Variant("CG, 120 it, armature 1e-4 kg", iterations=120, armature_kg=1e-4),
    Variant("CG, 100 it, armature 1e-4 kg", iterations=100, armature_kg=1e-4),
    Variant("CG, 120 it, armature 3e-4 kg", iterations=120, armature_kg=3e-4),
    CHOSEN,
    Variant("CG, 100 it, armature 1e-3 kg", iterations=100, armature_kg=1e-3),
    Variant("Newton, tol 1e-5, armature 1e-3 kg", solver="Newton", armature_kg=1e-3),
)
RIG_VARIANTS: tuple[Variant, ...] = (
    BASELINE,
    REFERENCE,
    Variant("CG, 150 it", iterations=150),
    Variant("CG, 120 it", iterations=120),
    Variant("CG, 150 it, armature 1e-4 kg", iterations=150, armature_kg=1e-4),
    Variant("CG, 120 it, armature 1e-4 kg", iterations=120, armature_kg=1e-4),
    Variant("CG, 100 it, armature 1e-4 kg", iterations=100, armature_kg=1e-4),
    CHOSEN,
)
QUICK_VARIANT = Variant("CG, 100 it, armature 1e-4 kg", iterations=100, armature_kg=1e-4)


@dataclass
class Settings:
    """How long each measurement runs (quick: a smoke test, not for the record)."""

    resolutions: tuple[int, ...] = (5, 6, 7)
    settle_s: float = 5.0
    steps: int = 300
    repeats: int = 3
    rig_s: float = 8.0
    window_s: tuple[float, float] = (5.0, 7.0)
    step_variants: tuple[Variant, ...] = STEP_VARIANTS
    rig_variants: tuple[Variant, ...] = RIG_VARIANTS
    rtf_variants: tuple[str, ...] = (CHOSEN.label, "CG, 120 it, armature 1e-4 kg")
    """Labels of the rig variants also run at every other resolution (RTF and warnings)."""


def faithful_block(resolution: int) -> FoamParams:
    """The default block with the faithful preset at `resolution` vertices along its longest extent."""
    return LIBRARY["block"].with_overrides(fidelity="faithful", resolution=resolution)


def foam_dofs(model: mujoco.MjModel) -> np.ndarray:
    """Dof addresses of the foam's vertex bodies (flexcomp names them foam_<i>)."""
    bodies = [i for i in range(model.nbody) if model.body(i).name.startswith(f"{FOAM_NAME}_")]
    return np.flatnonzero(np.isin(model.dof_bodyid, bodies))


def configure(model: mujoco.MjModel, variant: Variant) -> None:
    """Set `variant` on `model` in place (every field, so variants can follow one another)."""
    opt = model.opt
    opt.solver = int(getattr(mujoco.mjtSolver, f"mjSOL_{variant.solver.upper()}"))
    opt.tolerance = variant.tolerance
    opt.iterations = variant.iterations
    opt.ls_iterations = 50 if variant.ls_iterations is None else variant.ls_iterations
    opt.ls_tolerance = 0.01 if variant.ls_tolerance is None else variant.ls_tolerance
    opt.cone = int(getattr(mujoco.mjtCone, f"mjCONE_{variant.cone or 'PYRAMIDAL'}"))
    opt.disableflags = sum(int(getattr(mujoco.mjtDisableBit, f"mjDSBL_{f}")) for f in variant.disable)
    opt.enableflags = sum(int(getattr(mujoco.mjtEnableBit, f"mjENBL_{f}")) for f in variant.enable)
    dofs = foam_dofs(model)
    if not np.all(model.dof_armature[dofs] == variant.armature_kg):
        model.dof_armature[dofs] = variant.armature_kg
        mujoco.mj_setConst(model, mujoco.MjData(model))  # without it the armature is ignored


def warning_counts(data: mujoco.MjData) -> dict[str, int]:
    """MuJoCo warnings raised so far, by name."""
    return {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(data.warning) if w.number}


def grasped_state(resolution: int, settle_s: float) -> tuple[SimBackend, np.ndarray]:
    """A backend whose rig ran the compress procedure `settle_s` (baseline settings), and its state."""
    backend = SimBackend(faithful_block(resolution), tactile=False)
    backend.connect()
    Rig(backend, phases=PHASES).run(CompressController(), settle_s)
    model, data = backend.world.model, backend.world.data
    state = np.empty(mujoco.mj_stateSize(model, STATE))
    mujoco.mj_getState(model, data, state, STATE)
    return backend, state


def time_steps(model: mujoco.MjModel, data: mujoco.MjData, state: np.ndarray, steps: int) -> dict[str, Any]:
    """From `state`: ms per mj_step, median and max solver iterations, warnings, contacts at the end."""
    mujoco.mj_setState(model, data, state, STATE)
    mujoco.mj_forward(model, data)
    data.warning.number[:] = 0
    iterations = np.empty(steps, dtype=int)
    t0 = time.perf_counter()
    for k in range(steps):
        mujoco.mj_step(model, data)
        iterations[k] = data.solver_niter[: max(data.nisland, 1)].max()
    ms = (time.perf_counter() - t0) / steps * 1e3
    return {
        "ms": ms,
        "iterations": float(np.median(iterations)),
        "max_iterations": int(iterations.max()),
        "warnings": warning_counts(data),
        "ncon": int(data.ncon),
    }


class Probe:
    """What the hand would read (drive counts, distal coupling torques) and the foam's contact force."""

    def __init__(self, backend: SimBackend) -> None:
        self.model = backend.world.model
        fingers = backend.world.clutches.fingers
        self.drive_qpos = np.array([f.drive_qpos for f in fingers])
        self.couple_outer = [f.couple_outer for f in fingers]
        self.flex_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_FLEX, FOAM_NAME)
        self._wrench = np.zeros(6)

    def position_counts(self, data: mujoco.MjData) -> np.ndarray:
        """(3,) finger drive angles in encoder counts."""
        return data.qpos[self.drive_qpos] / units.INNER_RAD_PER_COUNT

    def torque_nm(self, data: mujoco.MjData) -> np.ndarray:
        """(3,) distal coupling torques (N*m): efc_force of each finger's outer coupling row."""
        rows = {int(i): f for i, f in zip(data.efc_id[: data.ne], data.efc_force[: data.ne], strict=True)}
        return np.array([rows.get(e, 0.0) for e in self.couple_outer])

    def force_n(self, data: mujoco.MjData) -> float:
        """Total normal contact force on the foam (N): hand and palm."""
        total = 0.0
        for i in range(data.ncon):
            if self.flex_id in data.contact.flex[i]:
                mujoco.mj_contactForce(self.model, data, i, self._wrench)
                total += self._wrench[0]
        return total


def replay(model: mujoco.MjModel, data: mujoco.MjData, state: np.ndarray, probe: Probe, steps: int) -> dict:
    """From `state`, `steps` mj_steps (controls held): the probe's readings after every step."""
    mujoco.mj_setState(model, data, state, STATE)
    mujoco.mj_forward(model, data)
    trace: dict[str, list] = {"position_counts": [], "torque_nm": [], "force_n": []}
    for _ in range(steps):
        mujoco.mj_step(model, data)
        trace["position_counts"].append(probe.position_counts(data))
        trace["torque_nm"].append(probe.torque_nm(data))
        trace["force_n"].append(probe.force_n(data))
    return {k: np.array(v) for k, v in trace.items()}


def compare(trace: dict, reference: dict) -> dict[str, float]:
    """Torque and force against `reference`: the difference of the means (worst finger), and the
    step-to-step jitter (standard deviation of one step's change), which a hand reading samples."""
    out = {}
    for k in ("torque_nm", "force_n"):
        out[f"mean_{k}"] = float(np.max(np.abs(trace[k].mean(0) - reference[k].mean(0))))
        out[f"jitter_{k}"] = float(np.std(np.diff(trace[k], axis=0)))
    out["position_counts"] = float(np.max(np.abs(trace["position_counts"] - reference["position_counts"])))
    return out


def step_study(resolution: int, s: Settings) -> dict[str, Any]:
    """Every step variant from one grasped state, interleaved; medians and per-round ratios."""
    backend, state = grasped_state(resolution, s.settle_s)
    model = backend.world.model
    data = mujoco.MjData(model)
    ncon0 = int(backend.world.data.ncon)
    rounds: dict[str, list[dict]] = {v.label: [] for v in s.step_variants}
    for _ in range(s.repeats):
        for v in s.step_variants:
            configure(model, v)
            rounds[v.label].append(time_steps(model, data, state, s.steps))
    probe = Probe(backend)
    traces = {}
    for v in (REFERENCE, *s.step_variants):
        configure(model, v)
        traces[v.label] = replay(model, data, state, probe, s.steps)
    configure(model, BASELINE)
    base = rounds[BASELINE.label]
    rows = []
    for v in s.step_variants:
        runs = rounds[v.label]
        rows.append(
            {
                "label": v.label,
                "ms": float(np.median([r["ms"] for r in runs])),
                "ratio": float(np.median([r["ms"] / b["ms"] for r, b in zip(runs, base, strict=True)])),
                "iterations": runs[0]["iterations"],
                "max_iterations": runs[0]["max_iterations"],
                "warnings": runs[0]["warnings"],
                "ncon": runs[0]["ncon"],
                "physics": compare(traces[v.label], traces[REFERENCE.label]),
            }
        )
    ref = traces[REFERENCE.label]
    summary = {
        "torque_nm": float(np.max(ref["torque_nm"].mean(0))),
        "force_n": float(ref["force_n"].mean()),
        **{f"jitter_{k}": float(np.std(np.diff(ref[k], axis=0))) for k in ("torque_nm", "force_n")},
    }
    return {"resolution": resolution, "nv": int(model.nv), "ncon": ncon0, "rows": rows, "reference": summary}


class Recorder:
    """Passes readings to the compress controller and keeps what the physics check compares."""

    def __init__(self, backend: SimBackend) -> None:
        self.inner = CompressController()
        self.backend = backend
        self.probe = Probe(backend)
        self.rows: dict[str, list] = {"t_s": [], "position_counts": [], "torque_nm": [], "force_n": []}

    @property
    def phase(self) -> str:
        return self.inner.phase

    def __call__(self, reading: HandReading) -> HandCommand | None:
        physical = units.hand_reading_to_physical(
            reading.position_counts, reading.velocity_counts, reading.strain_counts
        )
        self.rows["t_s"].append(reading.t_s)
        self.rows["position_counts"].append(np.asarray(reading.position_counts[:3], dtype=float))
        self.rows["torque_nm"].append(np.asarray(physical["torque_nm"], dtype=float))
        self.rows["force_n"].append(self.probe.force_n(self.backend.world.data))
        return self.inner(reading)

    def trace(self) -> dict[str, np.ndarray]:
        return {k: np.array(v) for k, v in self.rows.items()}


def rig_run(resolution: int, variant: Variant, duration_s: float) -> dict[str, Any]:
    """A whole compress run (hand + tactile) under `variant`: RTF, warnings and the recorded trace."""
    backend = SimBackend(faithful_block(resolution))
    configure(backend.world.model, variant)
    backend.connect()
    recorder = Recorder(backend)
    t0 = time.perf_counter()
    Rig(backend, phases=PHASES).run(recorder, duration_s)
    wall_s = time.perf_counter() - t0
    return {"rtf": duration_s / wall_s, "warnings": backend.world.warnings(), "trace": recorder.trace()}


def differences(trace: dict, reference: dict, window_s: tuple[float, float]) -> dict[str, float]:
    """Over `window_s`: largest differences from `reference` (counts, N*m, N), and the differences of
    the window means (torque per finger, force): the grasp's level, less sensitive to timing."""
    t = reference["t_s"]
    n = min(len(t), len(trace["t_s"]))
    sel = (t[:n] >= window_s[0]) & (t[:n] <= window_s[1])

    def part(key: str, which: dict) -> np.ndarray:
        return which[key][:n][sel]

    out = {k: float(np.max(np.abs(part(k, trace) - part(k, reference)))) for k in READINGS}
    for k in ("torque_nm", "force_n"):
        out[f"mean_{k}"] = float(np.max(np.abs(part(k, trace).mean(0) - part(k, reference).mean(0))))
    out["reference_torque_nm"] = float(np.max(np.abs(part("torque_nm", reference))))
    out["reference_mean_force_n"] = float(part("force_n", reference).mean())
    return out


def rig_study(resolution: int, s: Settings, variants: tuple[Variant, ...]) -> list[dict[str, Any]]:
    """Each variant's rig run and its differences from the baseline run."""
    runs = [(v, rig_run(resolution, v, s.rig_s)) for v in variants]
    baseline = next((r["trace"] for v, r in runs if v == BASELINE), None)
    converged = next((r["trace"] for v, r in runs if v == REFERENCE), None)
    rows = []
    for v, r in runs:
        row = {"label": v.label, "resolution": resolution, "rtf": r["rtf"], "warnings": r["warnings"]}
        if baseline is not None:
            row["diff"] = differences(r["trace"], baseline, s.window_s)
        if converged is not None:
            row["diff_converged"] = differences(r["trace"], converged, s.window_s)
        rows.append(row)
    return rows


def run(quick: bool = False) -> dict:
    """Step study at resolution 6, rig study of the rig variants at 6 and the best ones at 5 and 7."""
    s = Settings()
    if quick:
        s = Settings(
            resolutions=(5,),
            settle_s=1.0,
            steps=20,
            repeats=1,
            rig_s=1.5,
            window_s=(1.0, 1.5),
            step_variants=(BASELINE, QUICK_VARIANT),
            rig_variants=(BASELINE, QUICK_VARIANT),
        )
    main = 6 if 6 in s.resolutions else s.resolutions[0]
    steps = step_study(main, s)
    rig = rig_study(main, s, s.rig_variants)
    chosen = tuple(v for v in s.rig_variants if v in (BASELINE, REFERENCE) or v.label in s.rtf_variants)
    for resolution in s.resolutions:
        if resolution != main:
            rig += rig_study(resolution, s, chosen)
    return {"settings": s.__dict__ | {"resolution": main}, "steps": steps, "rig": rig}


def _warnings(w: dict[str, int]) -> str:
    return ", ".join(f"{k.removeprefix('mjWARN_')}: {v}" for k, v in w.items()) or "none"


def _diff(d: dict | None) -> str:
    if not d:
        return "- | - | -"
    return f"{d['position_counts']:.0f} | {d['torque_nm']:.3f} | {d['force_n']:.2f}"


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section: step table, then rig table."""
    s, steps = results["settings"], results["steps"]
    ref = steps["reference"]
    lines = [
        "## Faithful foam: solver settings (speed, iterations, warnings, physics)",
        "",
        f"Block, faithful preset, resolution {steps['resolution']} (nv {steps['nv']}, "
        f"{steps['ncon']} contacts in the grasp). *Step*: {s['steps']} mj_steps from one grasped "
        f"state (the compress run after {s['settle_s']:g} s, controls then held), restored before "
        f"each variant; medians of {s['repeats']} interleaved rounds, ratio to the baseline of the "
        "same round. Iterations: median (max) CG/Newton iterations per step. Physics, against the "
        f"converged solve ({REFERENCE.label}) over the same steps: the difference of the mean distal "
        f"coupling torque (worst finger; the reference holds {ref['torque_nm']:.3f} N*m) and of the "
        f"mean total normal contact force on the foam (reference {ref['force_n']:.1f} N), and the "
        "jitter of each: the standard deviation of one step's change, which a hand reading samples "
        f"(reference: {ref['jitter_torque_nm']:.4f} N*m, {ref['jitter_force_n']:.2f} N; the strain "
        "gauge's own noise is ~0.005 N*m).",
        "",
        "| variant | ms/step | vs baseline | iterations | warnings | torque mean diff (N*m) | "
        "torque jitter (N*m) | force mean diff (N) | force jitter (N) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in steps["rows"]:
        p = r["physics"]
        lines.append(
            f"| {r['label']} | {r['ms']:.2f} | {r['ratio']:.2f}x | {r['iterations']:.0f} "
            f"({r['max_iterations']}) | {_warnings(r['warnings'])} | {p['mean_torque_nm']:.4f} "
            f"| {p['jitter_torque_nm']:.4f} | {p['mean_force_n']:.2f} | {p['jitter_force_n']:.2f} |"
        )
    w0, w1 = s["window_s"]
    lines += [
        "",
        f"*Rig*: a whole {s['rig_s']:g} s compress run (hand + tactile) from rest under the variant: RTF "
        f"(one run each, not interleaved) and MuJoCo warnings of the run. Over {w0:g}-{w1:g} s of the hand "
        "samples: largest differences from the baseline run (position_counts, torque_nm, total normal "
        "contact force on the foam), and the difference of the window means (torque: worst finger). The run "
        "is sensitive to small differences (the grasp forms on contact and clutch events): the converged "
        "run's row is the baseline's own solver error, the scale to judge the others by.",
        "",
        "| resolution | variant | RTF | warnings | position (counts) | torque (N*m) | foam force (N) "
        "| mean torque (N*m) | mean force (N) | vs converged: mean torque, mean force |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results["rig"]:
        d, c = r.get("diff"), r.get("diff_converged")
        means = f"{d['mean_torque_nm']:.3f} | {d['mean_force_n']:.2f}" if d else "- | -"
        converged = f"{c['mean_torque_nm']:.3f}, {c['mean_force_n']:.2f}" if c else "-"
        lines.append(
            f"| {r['resolution']} | {r['label']} | {r['rtf']:.2f}x | {_warnings(r['warnings'])} | {_diff(d)} "
            f"| {means} | {converged} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
