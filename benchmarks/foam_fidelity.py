"""Foam fidelity: every library foam's discretizations against the FEM reference and analytic mechanics.

The bench is the one of benchmarks/fem_reference.py, rebuilt in MuJoCo: the object rests on a plate and a
rigid indenter on its -y side (a mocap body) presses it +y against a rigid wall touching its +y extreme;
the plate holds the object up (friction 0.8: at most 0.06 N against the foam's weight, which the FEM
ignores). The wall is frictionless, as the FEM's, except for the sphere foam: the FEM's symmetry planes
hold the ball in place, MuJoCo has none, and a ball pressed by a ball against a frictionless wall escapes,
so there the wall has friction 0.8 (on the block it stiffens the foam by ~8 %: a bias to remember for the
sphere foam's figures). Indenters: the fingertip-sized 23 x 50 mm flat punch on the blocks and the cylinder, a
12 mm-radius sphere on the sphere and the block, both with the fingers' contact parameters and friction
(models/barrett_mjcf/bh8.xml: solref 0.004, solimp 0.95-0.99, friction 1). Depth: ramp and hold at 2, 4
and 6 mm from first touch; the force is the indenter's y reaction averaged over the last third of each hold.

Scores, each against the size of what it measures:
- punch: the error outside the FEM bracket [slipping, bonded] (0 inside), relative to the bracket;
- sphere: relative error against the FEM (frictionless sphere);
- face profile at 6 mm: RMS of the y displacement of the indented side's vertices against the FEM's
  interpolated at the same points, beside the RMS of the FEM profile itself (a flat face scores that);
- uniaxial (blocks, cylinder: a plate wider than the object, frictionless): against E * A * strain;
- Hertz (the block, 2 mm sphere): against (4/3) E / (1 - nu^2) sqrt(R) d^1.5 (Johnson 1985, eq. 4.22),
  which ignores the block's finite size and the wall behind it (the FEM does not).
Speed: bench steps/s and real-time factor (the foam alone, with the indenter).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from dm_control import mjcf
from scipy.interpolate import griddata

from twin.sim.foam import LIBRARY, FoamParams
from twin.sim.scene import FOAM_NAME, PALM_SURFACE_Z_M, add_foam, compile_scene

PUNCH_HALF_M = (0.0115, 0.004, 0.025)
"""The BH8 fingertip's face: 23 mm wide, 50 mm tall (half extents; 8 mm thick)."""
SPHERE_RADIUS_M = 0.012
PLATE_TOP_Z_M = PALM_SURFACE_Z_M
"""The foam is composed resting on the palm (twin.sim.scene.add_foam); the plate stands in for the palm."""
DEPTHS_MM = (2.0, 4.0, 6.0)
SETTLE_S, RAMP_S, HOLD_S = 0.3, 0.4, 0.4
FINGER_SOLREF = (0.004, 1.0)
FINGER_SOLIMP = (0.95, 0.99, 0.001)
FINGER_FRICTION = 1.0
RIGID_SOLIMP = (0.9999, 0.9999, 0.001)
"""The bench's own wall and plate: as rigid as MuJoCo's soft contacts allow (they are not under test)."""
UNIAXIAL_HALF_M = (0.07, 0.004, 0.07)
"""The uniaxial plate (x, thickness, y half extents), wider than any library object."""


@dataclass(frozen=True)
class Config:
    """One discretization of the Pareto study: a fidelity preset with overrides, and a physics step."""

    label: str
    fidelity: str
    resolution: int | None = None
    dof: str | None = None
    timestep_s: float = 0.002
    calibrated: bool = True
    """The flex modulus scaled by the foam's calibration (twin.sim.calibration), or the bare young_pa."""

    @property
    def modulus_scale(self) -> float | None:
        """add_foam's override: None (the calibration) or 1 (the bare modulus)."""
        return None if self.calibrated else 1.0

    def foam(self, name: str) -> FoamParams:
        return LIBRARY[name].with_overrides(fidelity=self.fidelity, resolution=self.resolution, dof=self.dof)


def _bench(
    foam: FoamParams, indenter: str, timestep_s: float, modulus_scale: float | None = None
) -> mjcf.RootElement:
    """The bench around `foam`; the indenter and wall are placed after the foam settles (see _place)."""
    root = mjcf.RootElement(model="foam_fidelity")
    root.option.timestep = timestep_s
    root.option.integrator = "discrete"
    rigid = dict(solref=list(FINGER_SOLREF), solimp=list(RIGID_SOLIMP), priority=5)
    root.worldbody.add(
        "geom", name="plate", type="box", size=[0.1, 0.1, 0.005], pos=[0, 0, PLATE_TOP_Z_M - 0.005],
        condim=1 if indenter == "plate" else 3, friction=[0.8, 0.005, 0.0001], **rigid,
    )  # fmt: skip
    wall = root.worldbody.add("body", name="wall", mocap=True, pos=[0, 1.0, 0.1])
    # a ball pressed against a frictionless wall by a ball escapes (see above)
    grip = dict(friction=[0.8, 0.005, 0.0001]) if foam.shape == "sphere" else dict(condim=1)
    wall.add("geom", name="wall", type="box", size=[0.1, 0.005, 0.1], **grip, **rigid)
    body = root.worldbody.add("body", name="indenter", mocap=True, pos=[0, -1.0, 0.1])
    contact = dict(
        solref=list(FINGER_SOLREF), solimp=list(FINGER_SOLIMP), friction=[FINGER_FRICTION, 0.005, 0.0001]
    )
    if indenter == "sphere":
        body.add("geom", name="indenter", type="sphere", size=[SPHERE_RADIUS_M], **contact)
    elif indenter == "plate":
        half = [UNIAXIAL_HALF_M[0], UNIAXIAL_HALF_M[2], UNIAXIAL_HALF_M[1]]  # a horizontal plate
        body.add("geom", name="indenter", type="box", size=half, condim=1, **rigid)
    else:
        body.add("geom", name="indenter", type="box", size=list(PUNCH_HALF_M), **contact)
    add_foam(root, foam, modulus_scale=modulus_scale)
    return root


def _foam_vertices(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    flex = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, FOAM_NAME)
    adr, num = model.flex_vertadr[flex], model.flex_vertnum[flex]
    return data.flexvert_xpos[adr : adr + num].copy()


def _indenter_force_n(model: mujoco.MjModel, data: mujoco.MjData, geom: int, axis: int) -> float:
    """The force the indenter exerts on the foam along `axis` (N)."""
    wrench = np.zeros(6)
    total = 0.0
    for c in range(data.ncon):
        con = data.contact[c]
        if geom not in (con.geom[0], con.geom[1]):
            continue
        mujoco.mj_contactForce(model, data, c, wrench)
        world = con.frame.reshape(3, 3).T @ wrench[:3]  # force on geom2 from geom1, world frame
        total += world[axis] if con.geom[0] == geom else -world[axis]
    return float(total)


def simulate(
    foam: FoamParams, indenter: str, timestep_s: float = 0.002, modulus_scale: float | None = None
) -> dict[str, Any]:
    """Settle the foam on the plate, bring the wall and the indenter to touch, then ramp-hold 2/4/6 mm."""
    model = compile_scene(_bench(foam, indenter, timestep_s, modulus_scale))
    data = mujoco.MjData(model)
    radius = float(model.flex_radius[0])
    for _ in range(round(SETTLE_S / timestep_s)):
        mujoco.mj_step(model, data)
    rest = _foam_vertices(model, data)
    lo, hi = rest.min(axis=0), rest.max(axis=0)
    z_mid = (lo[2] + hi[2]) / 2
    if indenter == "plate":  # uniaxial: a frictionless plate presses the top down onto the frictionless plate
        start, axis, sign = np.array([0.0, 0.0, hi[2] + radius + UNIAXIAL_HALF_M[1]]), 2, -1.0
    else:
        data.mocap_pos[0] = [0.0, hi[1] + radius + 0.005, z_mid]
        half_y = SPHERE_RADIUS_M if indenter == "sphere" else PUNCH_HALF_M[1]
        start, axis, sign = np.array([0.0, lo[1] - radius - half_y, z_mid]), 1, 1.0
    geom = model.geom("indenter").id
    forces, wall_s, steps = [], 0.0, 0
    shape_6mm = None
    previous = 0.0
    n_ramp, n_hold = round(RAMP_S / timestep_s), round(HOLD_S / timestep_s)
    for depth in DEPTHS_MM:
        samples = []
        for i in range(n_ramp + n_hold):
            d = previous + (depth - previous) * min(1.0, (i + 1) / n_ramp)
            data.mocap_pos[1] = start
            data.mocap_pos[1, axis] += sign * d / 1e3
            t0 = time.perf_counter()
            mujoco.mj_step(model, data)
            wall_s += time.perf_counter() - t0
            steps += 1
            if i >= n_ramp + 2 * n_hold // 3:
                samples.append(sign * _indenter_force_n(model, data, geom, axis))
        forces.append(float(np.mean(samples)))
        previous = depth
        if depth == DEPTHS_MM[-1]:
            shape_6mm = _foam_vertices(model, data)
    warnings = {mujoco.mjtWarning(k).name: int(w.number) for k, w in enumerate(data.warning) if w.number}
    return {
        "force_n": forces,
        "rest": rest,
        "shape_6mm": shape_6mm,
        "bottom_z_m": float(lo[2]),
        "centre_z_m": float(z_mid),
        "steps_per_s": steps / wall_s,
        "rtf": steps * timestep_s / wall_s,
        "warnings": warnings,
        "vertices": len(rest),
        "penetration_mm": float(
            max(0.0, -min((c.dist for c in data.contact[: data.ncon]), default=0.0)) * 1e3
        ),
    }


@functools.cache
def _fem_cache() -> dict[str, Any]:
    """The FEM reference's cache (benchmarks/fem_reference.json), read once per process."""
    from benchmarks import fem_reference  # scikit-fem and gmsh: only where the FEM is read

    return fem_reference.load_cache()


def face_profile_error_mm(sim: dict[str, Any], case: str, foam: FoamParams) -> tuple[float, float]:
    """(RMS of the sim's indented-side y displacement against the FEM's, RMS of the FEM's own) at 6 mm (mm).

    Sim vertices on the -y side (those the FEM profile covers: within 2 mm of the surface seen from -y)
    are compared with the FEM profile interpolated at their rest (x, z)."""
    from benchmarks import fem_reference  # scikit-fem and gmsh: only where the FEM is read

    ref = fem_reference.profile(case, _fem_cache())
    rest, moved = sim["rest"], sim["shape_6mm"]
    z0 = sim["centre_z_m"] if foam.shape == "sphere" else sim["bottom_z_m"]
    xz = np.c_[rest[:, 0], rest[:, 2] - z0]
    y_front = griddata(np.c_[ref["x_m"], ref["z_m"]], ref["y_rest_m"], xz, method="linear")
    front = np.isfinite(y_front) & (rest[:, 1] - rest[:, 1].min() - (y_front - ref["y_rest_m"].min()) < 0.002)
    u_ref = griddata(np.c_[ref["x_m"], ref["z_m"]], ref["uy_m"], xz[front], method="linear")
    u_sim = moved[front, 1] - rest[front, 1]
    ok = np.isfinite(u_ref)
    err = float(np.sqrt(np.mean((u_sim[ok] - u_ref[ok]) ** 2)) * 1e3)
    scale = float(np.sqrt(np.mean(u_ref[ok] ** 2)) * 1e3)
    return err, scale


def mid_height_profile_mm(sim: dict[str, Any], case: str, foam: FoamParams) -> dict[str, list[float]]:
    """The indented side at 6 mm along its mid-height line: the sim's vertices within half an edge of it
    and the FEM's line, displacement against x (mm), for the face-profile plot."""
    from benchmarks import fem_reference

    ref = fem_reference.profile(case, _fem_cache())
    rest, moved = sim["rest"], sim["shape_6mm"]
    z_ref = 0.0 if foam.shape == "sphere" else foam.size_m[2] / 2
    nearest = ref["z_m"][np.argmin(np.abs(ref["z_m"] - z_ref))]  # the FEM's grid row nearest mid-height
    line = np.abs(ref["z_m"] - nearest) < 1e-9
    order = np.argsort(ref["x_m"][line])
    front = rest[:, 1] < rest[:, 1].min() + foam.edge_m / 2
    near = front & (np.abs(rest[:, 2] - sim["centre_z_m"]) < foam.edge_m / 2)
    return {
        "fem_x_mm": (ref["x_m"][line][order] * 1e3).tolist(),
        "fem_u_mm": (ref["uy_m"][line][order] * 1e3).tolist(),
        "sim_x_mm": (rest[near, 0] * 1e3).tolist(),
        "sim_u_mm": ((moved[near, 1] - rest[near, 1]) * 1e3).tolist(),
    }


def outside_bracket(value: float, low: float, high: float) -> float:
    """Relative distance of value outside [low, high] (0 inside), against the bracket's nearer end."""
    if value < low:
        return value / low - 1.0
    if value > high:
        return value / high - 1.0
    return 0.0


def hertz_force_n(foam: FoamParams, depth_m: float, radius_m: float = SPHERE_RADIUS_M) -> float:
    """Hertz: a rigid sphere on an elastic half-space (Johnson, Contact Mechanics, 1985, eq. 4.22-4.23)."""
    e_star = foam.young_pa / (1.0 - foam.poisson**2)
    return 4.0 / 3.0 * e_star * math.sqrt(radius_m) * depth_m**1.5


def uniaxial_force_n(foam: FoamParams, depth_m: float) -> float:
    """F = E A strain for a block squeezed along z between frictionless plates (laterally free)."""
    x, y, z = foam.size_m
    return foam.young_pa * x * y * depth_m / z


def evaluate(config: Config) -> dict[str, Any]:
    """Every library case for one discretization: errors against the FEM and analytic checks, and speed."""
    from benchmarks import fem_reference

    cache = _fem_cache()
    rows: dict[str, Any] = {}
    speed = []
    warnings: dict[str, int] = {}
    for case, (name, indenter) in _cases().items():
        foam = config.foam(name)
        sim = simulate(
            foam, "sphere" if indenter == "sphere" else "punch", config.timestep_s, config.modulus_scale
        )
        speed.append(sim["rtf"])
        for k, v in sim["warnings"].items():
            warnings[k] = warnings.get(k, 0) + v
        if indenter == "sphere":
            depths, ref = fem_reference.force_depth(f"{name}/sphere", cache)
            ref_at = np.interp(np.array(DEPTHS_MM) / 1e3, depths, ref)
            errors = [f / r - 1.0 for f, r in zip(sim["force_n"], ref_at, strict=True)]
            profile_case = f"{name}/sphere"
            extra = {"fem_n": ref_at.tolist()}
        else:
            _, bonded = fem_reference.force_depth(f"{name}/punch_bonded", cache)
            _, slipping = fem_reference.force_depth(f"{name}/punch_slipping", cache)
            triples = zip(sim["force_n"], slipping, bonded, strict=True)
            errors = [outside_bracket(f, s, b) for f, s, b in triples]
            profile_case = f"{name}/punch_bonded"
            extra = {"fem_bonded_n": bonded.tolist(), "fem_slipping_n": slipping.tolist()}
        face, face_scale = face_profile_error_mm(sim, profile_case, foam)
        line = mid_height_profile_mm(sim, profile_case, foam) if case == "block/punch" else None
        rows[case] = {
            "line": line,
            "force_n": sim["force_n"],
            "error": errors,
            "face_rms_mm": face,
            "face_scale_mm": face_scale,
            "rtf": sim["rtf"],
            "vertices": sim["vertices"],
            **extra,
        }
    uni_foam = config.foam("block")
    uni = simulate(uni_foam, "plate", config.timestep_s, config.modulus_scale)
    uni_ref = [uniaxial_force_n(uni_foam, d / 1e3) for d in DEPTHS_MM]
    sphere_block = rows["block/sphere"]
    hertz = hertz_force_n(uni_foam, DEPTHS_MM[0] / 1e3)
    return {
        "config": config,
        "cases": rows,
        "uniaxial": {"force_n": uni["force_n"], "analytic_n": uni_ref,
                     "error": [f / r - 1 for f, r in zip(uni["force_n"], uni_ref, strict=True)]},
        "hertz_2mm": {"force_n": sphere_block["force_n"][0], "analytic_n": hertz,
                      "fem_n": sphere_block["fem_n"][0]},
        "rtf_min": min(speed),
        "warnings": warnings,
    }  # fmt: skip


def _cases() -> dict[str, tuple[str, str]]:
    cases = {f"{o}/punch": (o, "punch") for o in ("block", "soft_block", "firm_block", "cylinder")}
    cases |= {"sphere/sphere": ("sphere", "sphere"), "block/sphere": ("block", "sphere")}
    return cases


CONFIGS: tuple[Config, ...] = (
    Config("fast, uncalibrated", "fast", calibrated=False),
    Config("fast, calibrated", "fast"),
    Config("faithful r6, uncalibrated", "faithful", 6, calibrated=False),
    Config("faithful r6, calibrated", "faithful", 6),
)
"""The two presets before and after their calibration against the FEM of the fingertips' contact: the flat
punch, the sphere and uniaxial compression are loads k was not fitted on. (The Pareto study of other
discretizations, on MuJoCo 3.17 and uncalibrated, is in git history: 3bb531c's BENCHMARKS.md.)"""
QUICK_CONFIGS = (
    Config("fast, calibrated", "fast"),
    Config("faithful r5, uncalibrated", "faithful", 5, calibrated=False),
)
CONVERGENCE_RESOLUTIONS = (6, 8, 10, 12)
"""The faithful block under the punch, refined, uncalibrated: does MuJoCo's flex converge to the FEM?"""


def convergence(resolutions: tuple[int, ...]) -> list[dict[str, Any]]:
    """The block/punch case of the faithful foam at each resolution: forces, bracket errors, face, speed."""
    from benchmarks import fem_reference

    _, bonded = fem_reference.force_depth("block/punch_bonded", _fem_cache())
    _, slipping = fem_reference.force_depth("block/punch_slipping", _fem_cache())
    rows = []
    for resolution in resolutions:
        foam = Config("", "faithful", resolution).foam("block")
        sim = simulate(foam, "punch", modulus_scale=1.0)  # MuJoCo's own flex under refinement
        errors = [outside_bracket(f, s, b) for f, s, b in zip(sim["force_n"], slipping, bonded, strict=True)]
        face, scale = face_profile_error_mm(sim, "block/punch_bonded", foam)
        rows.append(
            {"resolution": resolution, "vertices": sim["vertices"], "edge_mm": foam.edge_m * 1e3,
             "force_n": sim["force_n"], "error": errors, "face_rms_mm": face, "face_scale_mm": scale,
             "rtf": sim["rtf"], "warnings": sim["warnings"]}
        )  # fmt: skip
    return rows


def rig_rtf(config: Config, duration_s: float) -> float:
    """Real-time factor of the rig with the hand and tactile pads on the compress procedure (block)."""
    from benchmarks.realtime import _rig

    if config.timestep_s != 0.002:
        return float("nan")  # the rig's step is the hand model's (bh8.xml)
    return _rig(config.foam("block"), duration_s)


def run(quick: bool = False) -> dict[str, Any]:
    """Every configuration against the references, with the rig's speed for the block."""

    rows = []
    for config in QUICK_CONFIGS if quick else CONFIGS:
        result = evaluate(config)
        result["rig_rtf"] = rig_rtf(config, 2.0 if quick else 8.0)
        rows.append(result)
    cache = _fem_cache()
    conv = convergence(CONVERGENCE_RESOLUTIONS[:1] if quick else CONVERGENCE_RESOLUTIONS)
    return {"rows": rows, "convergence": conv, "fem": cache["provenance"], "fem_cases": cache["cases"]}


def _worst(row: dict[str, Any], kind: str) -> float:
    """Largest |error| over the cases of one kind (punch bracket or sphere) and depths."""
    errs = [abs(e) for case, r in row["cases"].items() if case.endswith(kind) for e in r["error"]]
    return max(errs)


def _rtf(value: float) -> str:
    """A real-time factor, or '-' where it was not measured (the rig runs at the hand model's step)."""
    return "-" if math.isnan(value) else f"{value:.2f}x"


def _pct(values: list[float]) -> str:
    return " / ".join(f"{100 * v:+.0f}%" for v in values)


def to_markdown(results: dict[str, Any]) -> str:
    """The BENCHMARKS.md section: the Pareto table, then per-case tables of the chosen presets."""
    fem = results["fem"]
    lines = [
        "## Foam fidelity: MuJoCo discretizations against an FEM reference and analytic mechanics",
        "",
        f"Reference: {fem['library']} ({fem['element']}; meshes by {fem['mesher']}), converged under "
        "refinement (the last refinement changed the 6 mm force by < 1 %, `benchmarks/fem_reference.json`), "
        f"boundary conditions: {fem['bcs']}. The MuJoCo bench (`benchmarks/foam_fidelity.py`) is the same "
        "geometry: a rigid 23 x 50 mm punch (blocks, cylinder) or a 12 mm-radius sphere (sphere, block) "
        "presses the foam against a rigid frictionless wall, with the fingers' contact parameters. Punch "
        "error: how far outside the FEM bracket [slipping, bonded] (0 inside). Face: RMS error of the "
        "indented side's displacement at 6 mm, beside the RMS of that displacement itself (what a flat face "
        "scores). Uniaxial: the block between frictionless plates against E A strain. Hertz: the block "
        "under the sphere at 2 mm against Johnson (1985) eq. 4.22, which ignores the block's finite size "
        "(the FEM's figure beside it). Speed: *bench*: the slowest case, foam and indenter alone; *rig*: "
        "the compress procedure with the hand and the 162-taxel pads (block).",
        "",
        "| discretization | vertices (block) | worst punch error | worst sphere error | worst face RMS "
        "(mm, of) | uniaxial 2/4/6 mm | bench RTF | rig RTF | MuJoCo warnings |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for row in results["rows"]:
        c = row["config"]
        face = max(row["cases"].values(), key=lambda r: r["face_rms_mm"])
        warn = ", ".join(f"{k}: {v}" for k, v in row["warnings"].items()) or "none"
        lines.append(
            f"| {c.label} | {row['cases']['block/punch']['vertices']} | {100 * _worst(row, 'punch'):.0f}% "
            f"| {100 * _worst(row, 'sphere'):.0f}% | {face['face_rms_mm']:.2f} ({face['face_scale_mm']:.2f}) "
            f"| {_pct(row['uniaxial']['error'])} | {row['rtf_min']:.2f}x | {_rtf(row['rig_rtf'])} | {warn} |"
        )
    for row in results["rows"]:
        c = row["config"]
        lines += [
            "",
            f"**{c.label}**: force at 2 / 4 / 6 mm against the reference "
            f"(Hertz at 2 mm: {row['hertz_2mm']['analytic_n']:.2f} N; FEM {row['hertz_2mm']['fem_n']:.2f} N; "
            f"this foam {row['hertz_2mm']['force_n']:.2f} N).",
            "",
            "| case | MuJoCo (N) | FEM (N) | error | face RMS at 6 mm (mm, of) |",
            "| --- | --- | --- | --- | --- |",
        ]
        for case, r in row["cases"].items():
            if "fem_n" in r:
                ref = " / ".join(f"{v:.2f}" for v in r["fem_n"])
            else:
                pairs = zip(r["fem_slipping_n"], r["fem_bonded_n"], strict=True)
                ref = " / ".join(f"{s:.2f}-{b:.2f}" for s, b in pairs)
            lines.append(
                f"| {case} | {' / '.join(f'{v:.2f}' for v in r['force_n'])} | {ref} | {_pct(r['error'])} "
                f"| {r['face_rms_mm']:.2f} ({r['face_scale_mm']:.2f}) |"
            )
    lines += [
        "",
        "**Convergence of the faithful foam, uncalibrated** (block, punch; a finer mesh than any preset, to "
        "see whether MuJoCo's flex elasticity tends to the FEM as its mesh is refined):",
        "",
        "| resolution | edge (mm) | vertices | force 2/4/6 mm (N) | outside the FEM bracket "
        "| face RMS at 6 mm "
        "(mm, of) | bench RTF | MuJoCo warnings |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results["convergence"]:
        warn = ", ".join(f"{k}: {v}" for k, v in r["warnings"].items()) or "none"
        lines.append(
            f"| {r['resolution']} | {r['edge_mm']:.1f} | {r['vertices']} "
            f"| {' / '.join(f'{v:.2f}' for v in r['force_n'])} | {_pct(r['error'])} "
            f"| {r['face_rms_mm']:.2f} ({r['face_scale_mm']:.2f}) | {r['rtf']:.3f}x | {warn} |"
        )
    lines += [
        "",
        "![force against depth, FEM bracket shaded](benchmarks/foam_fidelity.png)",
        "",
        "![the block's face at 6 mm along its mid-height line](benchmarks/foam_fidelity_profile.png)",
        "",
    ]
    return "\n".join(lines) + "\n"


def plot(results: dict[str, Any], path: str) -> None:
    """Force against depth per case: the FEM (bracket shaded for the punch) and every discretization."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = list(results["rows"][0]["cases"])
    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5))
    fem = results["fem_cases"]
    for ax, case in zip(axes.ravel(), cases, strict=True):
        name, kind = case.split("/")
        if kind == "punch":
            b, s = fem[f"{name}/punch_bonded"], fem[f"{name}/punch_slipping"]
            d = np.r_[0.0, np.array(b["depths_m"]) * 1e3]
            ax.fill_between(d, np.r_[0.0, s["force_n"]], np.r_[0.0, b["force_n"]], color="0.7", label="FEM")
        else:
            e = fem[f"{name}/sphere"]
            ax.plot(
                np.r_[0.0, np.array(e["depths_m"]) * 1e3], np.r_[0.0, e["force_n"]], "k", lw=2, label="FEM"
            )
        for row in results["rows"]:
            ax.plot((0, *DEPTHS_MM), (0, *row["cases"][case]["force_n"]), "o-", ms=3, lw=1,
                    label=row["config"].label)  # fmt: skip
        ax.set_title(case)
        ax.set_xlabel("depth (mm)")
        ax.set_ylabel("force (N)")
    axes.ravel()[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    profile_plot(results, path.replace(".png", "_profile.png"))


def profile_plot(results: dict[str, Any], path: str) -> None:
    """The block's indented face at 6 mm along its mid-height line: the FEM and each discretization."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    first = results["rows"][0]["cases"]["block/punch"]["line"]
    ax.plot(first["fem_x_mm"], first["fem_u_mm"], "k", lw=2, label="FEM (bonded punch)")
    ax.axvspan(-PUNCH_HALF_M[0] * 1e3, PUNCH_HALF_M[0] * 1e3, color="0.9", label="punch")
    for row in results["rows"]:
        line = row["cases"]["block/punch"]["line"]
        order = np.argsort(line["sim_x_mm"])
        ax.plot(np.array(line["sim_x_mm"])[order], np.array(line["sim_u_mm"])[order], "o-", ms=3, lw=1,
                label=row["config"].label)  # fmt: skip
    ax.set_xlabel("x across the face (mm)")
    ax.set_ylabel("face displacement at 6 mm (mm)")
    ax.set_title("block under the fingertip-sized punch: the face at mid-height")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
