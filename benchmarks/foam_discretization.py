"""Foam discretization: fidelity vs speed against a fine full-dof reference.

A fingertip-sized rigid indenter (a 50 x 23 mm face, on a mocap body) presses horizontally into the
library block, which rests on a plate against a fixed wall on its far side (compressed as between
fingers). Depth: holds at 2, 4, 6 mm, then one 0-6 mm cycle at 0.5 Hz. For each discretization we
report indenter force error vs the reference (per hold and RMS over the cycle), the RMS error of the
indented face's shape at 6 mm, steps/s and real-time factor, and MuJoCo warnings.
"""

from __future__ import annotations

import math
import time

import mujoco
import numpy as np
from dm_control import mjcf
from scipy.interpolate import griddata

from twin.sim.foam import LIBRARY
from twin.sim.scene import FOAM_NAME, add_foam, compile_scene

HOLDS_MM = (2.0, 4.0, 6.0)
HOLD_S, RAMP_S, CYCLE_S = 0.6, 0.3, 2.0
INDENTER_HALF_M = (0.0115, 0.004, 0.025)  # 23 mm wide, 50 mm tall face, like the BH8 fingertip
PALM_Z = 0.075


def depth_profile_mm(t: float) -> float:
    """Ramp-hold to each depth, then one sinusoidal cycle 0 -> 6 -> 0 mm."""
    t0 = 0.0
    prev = 0.0
    for d in HOLDS_MM:
        if t < t0 + RAMP_S:
            return prev + (d - prev) * (t - t0) / RAMP_S
        if t < t0 + RAMP_S + HOLD_S:
            return d
        t0 += RAMP_S + HOLD_S
        prev = d
    if t < t0 + RAMP_S:
        return prev * (1 - (t - t0) / RAMP_S)
    tc = t - t0 - RAMP_S
    return 3.0 * (1 - math.cos(2 * math.pi * tc / CYCLE_S)) if tc < CYCLE_S else 0.0


def total_time_s() -> float:
    """Length of the depth profile (s)."""
    return len(HOLDS_MM) * (RAMP_S + HOLD_S) + RAMP_S + CYCLE_S


def build(dof: str, resolution: int, timestep: float) -> tuple[mujoco.MjModel, float]:
    """The test bench and the indenter's start position (y of the foam's near face)."""
    foam = LIBRARY["block"].with_overrides(dof=dof, resolution=resolution)
    root = mjcf.RootElement(model="indentation")
    root.option.timestep = timestep
    root.option.integrator = "discrete"
    half_y = foam.size_m[1] / 2
    root.worldbody.add("geom", name="plate", type="box", size=[0.06, 0.06, 0.005], pos=[0, 0, PALM_Z - 0.005])
    root.worldbody.add(
        "geom", name="wall", type="box", size=[0.06, 0.005, 0.05], pos=[0, half_y + 0.005, 0.12]
    )
    z_mid = PALM_Z + 0.001 + foam.size_m[2] / 2
    body = root.worldbody.add(
        "body", name="indenter", mocap=True, pos=[0, -half_y - INDENTER_HALF_M[1], z_mid]
    )
    body.add("geom", name="indenter", type="box", size=list(INDENTER_HALF_M), rgba=[0.7, 0.7, 0.75, 1])
    add_foam(root, foam)
    return compile_scene(root), -half_y


def simulate(dof: str, resolution: int, timestep: float) -> dict:
    """Run the profile; force trace, face shape at the 6 mm hold, speed, warnings."""
    model, face_y = build(dof, resolution, timestep)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    indenter = model.geom("indenter").id
    flex = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, FOAM_NAME)
    adr, num = model.flex_vertadr[flex], model.flex_vertnum[flex]
    rest = data.flexvert_xpos[adr : adr + num].copy()
    face = np.abs(rest[:, 1] - face_y) < 1e-4
    y0 = data.mocap_pos[0, 1]
    n = round(total_time_s() / timestep)
    times, forces, depths = [], [], []
    shape = None
    wrench = np.zeros(6)
    t_shape = 3 * (RAMP_S + HOLD_S) - 0.05  # end of the 6 mm hold
    wall = 0.0
    for i in range(n):
        t = i * timestep
        depth = depth_profile_mm(t)
        data.mocap_pos[0, 1] = y0 + depth / 1e3
        t0 = time.perf_counter()
        mujoco.mj_step(model, data)
        wall += time.perf_counter() - t0
        force = 0.0
        for c in range(data.ncon):
            con = data.contact[c]
            if indenter in (con.geom1, con.geom2):
                mujoco.mj_contactForce(model, data, c, wrench)
                force += wrench[0]
        times.append(t)
        forces.append(force)
        depths.append(depth)
        if shape is None and t >= t_shape:
            shape = data.flexvert_xpos[adr : adr + num][face].copy()
    warnings = {mujoco.mjtWarning(k).name: int(w.number) for k, w in enumerate(data.warning) if w.number}
    return {
        "dof": dof,
        "resolution": resolution,
        "timestep_s": timestep,
        "t": np.array(times),
        "force_n": np.array(forces),
        "depth_mm": np.array(depths),
        "face": shape,
        "steps_per_s": n / wall,
        "rtf": n * timestep / wall,
        "warnings": warnings,
    }


def _hold_force(r: dict, depth_mm: float) -> float:
    """Mean force over the last third of a hold."""
    k = HOLDS_MM.index(depth_mm)
    end = (k + 1) * (RAMP_S + HOLD_S)
    sel = (r["t"] > end - HOLD_S / 3) & (r["t"] < end)
    return float(r["force_n"][sel].mean())


def _cycle(r: dict, grid_t: np.ndarray) -> np.ndarray:
    return np.interp(grid_t, r["t"], r["force_n"])


def _face_error_mm(r: dict, ref: dict) -> float:
    """RMS difference of the indented face's normal displacement, on the reference's face points."""
    xz_ref, y_ref = ref["face"][:, [0, 2]], ref["face"][:, 1]
    y = griddata(r["face"][:, [0, 2]], r["face"][:, 1], xz_ref, method="linear")
    ok = np.isfinite(y)
    return float(np.sqrt(np.mean((y[ok] - y_ref[ok]) ** 2)) * 1e3)


def compare(r: dict, ref: dict) -> dict:
    """Errors of one case against the reference."""
    t0 = len(HOLDS_MM) * (RAMP_S + HOLD_S) + RAMP_S
    grid = np.linspace(t0, t0 + CYCLE_S, 200)
    ref_cycle = _cycle(ref, grid)
    rms = np.sqrt(np.mean((_cycle(r, grid) - ref_cycle) ** 2)) / np.abs(ref_cycle).max()
    return {
        "hold_error_pct": [100 * (_hold_force(r, d) / _hold_force(ref, d) - 1) for d in HOLDS_MM],
        "cycle_rms_pct": 100 * float(rms),
        "face_rms_mm": _face_error_mm(r, ref),
        "hold_force_n": [_hold_force(r, d) for d in HOLDS_MM],
    }


def run(quick: bool = False) -> dict:
    """All cases and the reference; quick=True uses a coarse reference (a smoke test)."""
    ref_res, ref_dt = (4, 0.001) if quick else (8, 0.0005)
    reference = simulate("full", ref_res, ref_dt)
    check = simulate("full", ref_res - 1, ref_dt)
    cases = [("trilinear", 4, 0.002)] if quick else [
        ("trilinear", 4, 0.002), ("trilinear", 5, 0.002), ("quadratic", 4, 0.002),
        ("quadratic", 5, 0.002), ("full", 4, 0.002), ("full", 4, 0.001), ("full", 5, 0.001),
    ]  # fmt: skip
    rows = []
    for dof, res, dt in cases:
        r = simulate(dof, res, dt)
        keys = ("dof", "resolution", "timestep_s", "steps_per_s", "rtf", "warnings")
        rows.append(
            {**{k: r[k] for k in keys}, **compare(r, reference), "trace": (r["depth_mm"], r["force_n"])}
        )
    convergence = compare(check, reference)
    return {
        "reference": {"dof": "full", "resolution": ref_res, "timestep_s": ref_dt,
                      "hold_force_n": [_hold_force(reference, d) for d in HOLDS_MM],
                      "warnings": reference["warnings"],
                      "trace": (reference["depth_mm"], reference["force_n"])},
        "convergence": {"resolution": ref_res - 1, **convergence},
        "rows": rows,
    }  # fmt: skip


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    ref, conv = results["reference"], results["convergence"]
    lines = [
        "## Foam discretization: fidelity vs speed",
        "",
        "Library block (60 x 60 x 70 mm, E = 40 kPa, nu = 0.3) pressed by a rigid 23 x 50 mm fingertip-sized "
        "indenter against a fixed wall; holds at 2/4/6 mm, then a 0-6 mm cycle at 0.5 Hz "
        "(`benchmarks/foam_discretization.py`). Reference: `full`, resolution "
        f"{ref['resolution']}, step {ref['timestep_s'] * 1e3:g} ms, hold forces "
        + ", ".join(f"{f:.2f}" for f in ref["hold_force_n"])
        + f" N. Its convergence: resolution {conv['resolution']} differs by "
        + ", ".join(f"{e:+.1f}%" for e in conv["hold_error_pct"])
        + f" at the holds and {conv['face_rms_mm']:.2f} mm on the face. Reference warnings: "
        + (", ".join(f"{k}: {v}" for k, v in ref["warnings"].items()) or "none")
        + ".",
        "",
        "| dof | resolution | step (ms) | steps/s | RTF (foam alone) | force error 2/4/6 mm "
        "| cycle RMS force error | face RMS error at 6 mm | warnings |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results["rows"]:
        warn = ", ".join(f"{k}: {v}" for k, v in r["warnings"].items()) or "none"
        errs = " / ".join(f"{e:+.0f}%" for e in r["hold_error_pct"])
        lines.append(
            f"| {r['dof']} | {r['resolution']} | {r['timestep_s'] * 1e3:g} | {r['steps_per_s']:.0f} "
            f"| {r['rtf']:.1f}x | {errs} | {r['cycle_rms_pct']:.0f}% | {r['face_rms_mm']:.2f} mm | {warn} |"
        )
    lines += [
        "",
        "![indenter force vs depth per discretization](benchmarks/foam_discretization.png)",
        "",
        "**Default: `trilinear`, resolution 4.** It is the only discretization that keeps the rig with the "
        "hand at >= 3x real time (the table above this one), but it can only deform through its 8 corner "
        "nodes: under a fingertip-sized dent it is 5-7x stiffer than the reference and its face shape is "
        "off by ~2 mm, so its `young_pa` acts as an effective modulus for whole-object squeezing, not the "
        "material's local modulus. For local indentation (tactile pads, contours) use `--dof full "
        "--resolution 5` (within ~10% of the reference, well below real time) or `quadratic`.",
    ]
    return "\n".join(lines) + "\n"


def plot(results: dict, path: str) -> None:
    """Force vs depth per discretization (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    d, f = results["reference"]["trace"]
    ax.plot(d, f, "k", lw=2, label="reference (full, fine)")
    for r in results["rows"]:
        d, f = r["trace"]
        ax.plot(d, f, lw=1, label=f"{r['dof']} r{r['resolution']} {r['timestep_s'] * 1e3:g} ms")
    ax.set_xlabel("indentation depth (mm)")
    ax.set_ylabel("indenter force (N)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    res = run()
    print(to_markdown(res))
    plot(res, "benchmarks/foam_discretization.png")
