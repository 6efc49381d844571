"""Real-to-sim: the twin's foam parameters that make replays of a run reproduce its measurements.

Rollout-based least squares: each candidate (Young's modulus, elasticity damping, Poisson ratio) is
a replay of the run's recorded commands (twin.sim.replay); the residuals are the measured minus the
replayed finger counts, distal torques and fingertip forces, each scaled by its sensor's resolution.
The sum of squares has narrow valleys (first contact and breakaway move with the foam), so the
search is a coarse-to-fine grid per parameter (modulus over its whole range first), then scipy's
trust-region least squares polishes all parameters together. Every batch of candidates (a grid
stage, a finite-difference Jacobian) is replayed in parallel processes: the clutch runs in Python
between steps, so mujoco.rollout's native threads cannot run this model.

The modulus starts from `twin identify`'s estimate (twin.sim.modulus) or a scan of its whole range; the
other parameters start at the run's own description of the object, which on hardware is the researcher's.
Identifiability is judged by replaying, not by the formal covariance (the residuals are not white:
first-contact timing and stick-slip make them so). Each other parameter is moved 25 % either way and
the modulus allowed to follow (a profile): unless the residual RMS then rises by
IDENTIFIABLE_RMS_RISE, the run cannot tell that parameter apart, and it is held at the description
rather than traded against the modulus. From a compress run the Poisson ratio trades against the
modulus along a valley (a 25 % change moves E ~8 %) and the elasticity damping barely shows.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from twin.interface.devices import TAXEL_COUNT_MAX
from twin.interface.errors import ConfigError, SimulationUnstableError
from twin.processes import worker_pool
from twin.recording.reader import Run
from twin.sim.foam import LIBRARY, FoamParams
from twin.sim.replay import Commands, Replay, replay
from twin.tactile.layout import FINGERTIP_PADS, LAYOUT
from twin.validation import check_run_metadata

PARAMS = ("young_pa", "damping", "poisson")
BOUNDS = {"young_pa": (5e3, 5e5), "damping": (2e-4, 2e-2), "poisson": (0.05, 0.45)}
LOG_PARAMS = {"young_pa", "damping"}
"""Searched in log space: a modulus is as uncertain at 10 kPa as at 100 kPa, relatively."""
SCALE_COUNTS = 5.0
SCALE_TORQUE_NM = 0.0085
"""One strain-gauge count (eq. 2)."""
SCALE_FORCE_N = 0.25
FIT_CYCLES = 3
"""Compression cycles replayed after the grasp: enough to pin the modulus, few enough to be quick."""
ZOOM_POINTS = 6
"""Candidates per grid stage: three rounds of two parallel replays."""
ZOOM_SPAN = {"young_pa": math.log(1.5), "poisson": 0.1, "damping": math.log(4.0)}
"""Half-width of a zoom around the current best (search coordinates); the first modulus zoom spans
the whole bound instead."""
POLISH_EVALUATIONS = 8
PROFILE_SPAN = math.log(1.15)
"""How far the modulus may follow a probed parameter: a 25 % Poisson move shifts it ~8 %."""
PROBE = 0.25
"""Relative move of each fitted parameter in the identifiability probe."""
IDENTIFIABLE_RMS_RISE = 0.10
"""A 25 % move must raise the residual RMS by 10 % for the parameter to count as identified: the
elasticity damping shows only in the touch and raised it by 5-8 %, and fitted from there it wandered
to 4x the truth; the Poisson ratio raises it by ~30 %."""
START = {"young_pa": 4e4}
"""The modulus' first guess when neither `--young` nor `twin identify` gives one (then it is scanned over
its whole range anyway). Never the run's recorded modulus: on a sim run that is the truth under test."""
FD_STEP = 0.01
"""Finite-difference step of the final polish, in search coordinates (1 % of a log parameter)."""


class FitError(ConfigError):
    """The run cannot be fitted (not a sim-describable run, no commands, nothing to fit)."""


def _identified_young_pa(path: Path, foam: FoamParams | None, workers: int) -> float | None:
    """E from `twin identify`'s engine (twin.sim.modulus), or None where it cannot say (a start: however
    wide its interval)."""
    from twin.sim.modulus import EstimateError, estimate_modulus

    try:
        return estimate_modulus(path, description=foam, workers=workers, precision=None).young_pa
    except (EstimateError, ValueError, KeyError):  # no pads, no compression, not a foam: scan instead
        return None


def recorded_young_pa(path: Path, foam: FoamParams) -> float | None:
    """E that `twin identify` already inferred for this run and this object, from RUN/identify (its
    default output), so a fit after an identification does not run the same simulations again; None where
    there is none, it describes another object, or the file is not one identify wrote (never an error:
    the fit then estimates)."""
    from twin.identify.report import RESULTS_FILE

    try:
        material = json.loads((path / "identify" / RESULTS_FILE).read_text(encoding="utf-8"))["material"]
        young_pa, obj = material["young_pa"], material["object"]
        same = obj["shape"] == foam.shape and np.allclose(obj["size_m"], foam.size_m, rtol=0, atol=1e-6)
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return None
    low, high = BOUNDS["young_pa"]
    if not (same and isinstance(young_pa, int | float) and low <= young_pa <= high):
        return None
    return float(young_pa)


def foam_of_run(run: Run) -> FoamParams:
    """The foam described by the run's metadata: the sim's full record, else the library object the
    run was told it held (a hardware run's `object_name`, from `twin.compress`/`twin.run`)."""
    obj = run.metadata.get("object")
    if not obj:
        experiment = run.metadata.get("experiment")
        named = experiment.get("object") if isinstance(experiment, dict) else None
        if isinstance(named, str) and named in LIBRARY:
            return LIBRARY[named]
        said = (  # "none": an empty hand (a free run); "unnamed": a run told nothing (twin.api)
            f"names its object {named!r}, not a library object"
            if named and named not in ("none", "unnamed")
            else "does not describe its object"
        )
        raise FitError(f"{run.path}: the run {said}; name it with --object (and --size-mm)")
    keys = set(FoamParams.__dataclass_fields__)
    given = {k: (tuple(v) if isinstance(v, list) else v) for k, v in obj.items() if k in keys}
    try:
        return FoamParams(**given)
    except TypeError as exc:
        raise FitError(f"{run.path}: the run's object is incomplete ({exc})") from None


def fit_window_s(run: Run) -> float:
    """Replay up to the grasp plus FIT_CYCLES compression cycles (or the whole run if shorter)."""
    phases = tuple(run.metadata.get("phases", ()))
    cmd = run.stream("command")
    end = float(cmd.t_s[-1])
    if "compress" not in phases:
        return end
    in_compress = cmd["phase"] == phases.index("compress")
    if not in_compress.any():
        return end
    period = 1.0 / run.metadata.get("experiment", {}).get("profile", {}).get("frequency_hz", 0.5)
    return min(end, float(cmd.t_s[in_compress][0]) + 0.5 + FIT_CYCLES * period)


@dataclass(frozen=True)
class Measured:
    """The run's measurements over the fit window, on the hand clock."""

    position_counts: NDArray[np.float64]
    torque_nm: NDArray[np.float64]
    force_n: NDArray[np.float64]
    """(n, 2): F1 + F2 fingertip forces (they trade load at 15 Hz on a held object), and F3's;
    NaN where a taxel of those pads was saturated (its pressure, hence the force, is clipped)."""

    @classmethod
    def from_run(cls, run: Run, commands: Commands) -> Measured:
        """Measurements at the replay's sample times."""
        hand = run.stream("hand")
        n = len(commands.sample_t_s)
        if "tactile" in run.streams and len(run.stream("tactile")):
            tac = run.stream("tactile")
            tips = np.column_stack(
                [np.interp(commands.sample_t_s, tac.t_s, tac["pad_force_n"][:, k]) for k in range(3)]
            )
            full = tac["counts"] >= TAXEL_COUNT_MAX
            scan = np.clip(np.searchsorted(tac.t_s, commands.sample_t_s), 0, len(tac) - 1)
            for k, pad in enumerate(FINGERTIP_PADS):
                hit = full[:, LAYOUT.taxels_of(pad)].any(axis=1)
                tips[hit[scan] | hit[np.maximum(scan - 1, 0)], k] = np.nan
        else:
            tips = np.full((n, 3), np.nan)
        return cls(
            hand["position_counts"][:n, :3].astype(float), hand["torque_nm"][:n].astype(float), _forces(tips)
        )


def _forces(tips: NDArray) -> NDArray:
    return np.column_stack([tips[:, 0] + tips[:, 1], tips[:, 2]])


def residuals(measured: Measured, sim: Replay) -> NDArray[np.float64]:
    """Scaled residuals: counts, torques and (where measured) fingertip forces."""
    parts = [
        ((sim.position_counts - measured.position_counts) / SCALE_COUNTS).ravel(),
        ((sim.torque_nm - measured.torque_nm) / SCALE_TORQUE_NM).ravel(),
    ]
    if np.isfinite(measured.force_n).any():
        diff = (_forces(sim.tip_force_n) - measured.force_n) / SCALE_FORCE_N
        parts.append(np.nan_to_num(diff, nan=0.0).ravel())  # saturated samples weigh nothing
    return np.concatenate(parts)


def rms_by_channel(measured: Measured, sim: Replay) -> dict[str, float]:
    """RMS differences in physical units."""
    out = {
        "position_counts": float(np.sqrt(np.mean((sim.position_counts - measured.position_counts) ** 2))),
        "torque_nm": float(np.sqrt(np.mean((sim.torque_nm - measured.torque_nm) ** 2))),
    }
    if np.isfinite(measured.force_n).any():
        out["force_n"] = float(np.sqrt(np.nanmean((_forces(sim.tip_force_n) - measured.force_n) ** 2)))
    return out


# --- worker side: each process keeps the run's commands and base foam -------------------------
_WORKER: dict = {}


def _init_worker(base: FoamParams, commands: Commands, names: tuple[str, ...]) -> None:
    _WORKER.update(base=base, commands=commands, names=names)


def _key(x: Sequence[float]) -> tuple[float, ...]:
    return tuple(np.round(np.asarray(x, dtype=float), 12))


def _to_params(x: Sequence[float], names: Sequence[str]) -> dict[str, float]:
    return {n: (math.exp(v) if n in LOG_PARAMS else float(v)) for n, v in zip(names, x, strict=True)}


def _replay_x(x: Sequence[float]) -> Replay:
    params = _to_params(x, _WORKER["names"])
    try:
        return replay(_WORKER["base"].with_overrides(**params), _WORKER["commands"])
    except SimulationUnstableError as exc:  # say which candidate: the fit's search put it there
        given = ", ".join(f"{k} {v:.4g}" for k, v in params.items())
        raise SimulationUnstableError(f"replaying the candidate {given}: {exc}") from None


@dataclass
class FitResult:
    """What `twin fit` reports."""

    run_path: Path
    names: tuple[str, ...]
    initial: dict[str, float]
    fitted: dict[str, float]
    sigma: dict[str, float]
    """Formal 1-sigma from the final Jacobian (optimistic: the residuals are not white)."""
    sensitivity: dict[str, float]
    """Residual RMS rise (fraction) when the parameter moves 25 % from its fit, the smaller of both ways."""
    identifiable: dict[str, bool]
    start_from: str
    """Where the modulus search started: 'identify' (its estimate), 'scan' (the whole range) or 'given'."""
    held: list[str]
    """Parameters left at the run's description: the run could not tell them apart (see identifiable)."""
    rms_initial: dict[str, float]
    rms_fitted: dict[str, float]
    evaluations: int
    wall_s: float
    window_s: float
    twin_truth: dict[str, float] = field(default_factory=dict)
    measured: Measured | None = None
    sim_initial: Replay | None = None
    sim_fitted: Replay | None = None

    def to_json(self) -> dict:
        """The results file's content."""
        out = {
            "run": str(self.run_path),
            "fitted": self.fitted,
            "sigma_formal": self.sigma,
            "sensitivity_rms_rise_at_25pct": self.sensitivity,
            "identifiable": self.identifiable,
            "initial": self.initial,
            "start_from": self.start_from,
            "held_at_description": self.held,
            "rms_initial": self.rms_initial,
            "rms_fitted": self.rms_fitted,
            "evaluations": self.evaluations,
            "wall_s": self.wall_s,
            "window_s": self.window_s,
        }
        if self.twin_truth:
            out["twin_truth"] = self.twin_truth
            out["error"] = {
                k: self.fitted[k] / v - 1.0 for k, v in self.twin_truth.items() if k in self.fitted and v
            }
        return out


def fit_run(
    run_path: Path | str,
    *,
    names: Sequence[str] = PARAMS,
    workers: int = 2,
    initial: dict[str, float] | None = None,
    progress: Callable[[int, float], None] | None = None,
    foam: FoamParams | None = None,
) -> FitResult:
    """Fit the named foam parameters of the twin to a recorded run.

    `foam` describes the object where the run does not (a hardware run): its geometry, density and
    friction are kept, the named parameters fitted."""
    started = time.perf_counter()
    run = Run(run_path)
    check_run_metadata(run.info, run.path / "run.json")  # types of what the fit reads: one line if not
    for stream in ("hand", "command"):
        if stream not in run.streams or not len(run.stream(stream)):
            raise FitError(
                f"{run.path}: no '{stream}' stream; a replay needs the run's commands and readings"
            )
    unknown = set(names) - set(PARAMS)
    if unknown:
        raise FitError(
            f"unknown fit parameter(s) {', '.join(sorted(unknown))} (choose from {', '.join(PARAMS)})"
        )
    names = tuple(names)
    base = foam if foam is not None else foam_of_run(run)
    window = fit_window_s(run)
    commands = Commands.from_run(run, until_s=window)
    measured = Measured.from_run(run, commands)
    described = {n: float(getattr(base, n)) for n in names}
    start = dict(described)  # the others start (and may stay) where the run's description has them
    start_from = "described"
    if "young_pa" in names:
        start_from = "given" if "young_pa" in (initial or {}) else "scan"
        start["young_pa"] = (initial or {}).get("young_pa", START["young_pa"])
        if start_from == "scan":  # twin identify's estimate, where it has one (recorded, else made now)
            recorded = recorded_young_pa(run.path, base)
            if recorded is not None:
                start["young_pa"], start_from = recorded, "identify (recorded)"
            else:
                named_only = foam is None and not run.metadata.get("object")  # the library object it named
                identified = _identified_young_pa(run.path, base if named_only else foam, workers)
                if identified is not None:
                    start["young_pa"], start_from = identified, "identify"
    truth = dict(described) if run.metadata.get("backend") == "sim" else {}
    lo = np.array([math.log(BOUNDS[n][0]) if n in LOG_PARAMS else BOUNDS[n][0] for n in names])
    hi = np.array([math.log(BOUNDS[n][1]) if n in LOG_PARAMS else BOUNDS[n][1] for n in names])
    cache: dict[tuple[float, ...], Replay] = {}
    evaluations = 0

    # spawned workers that die with this process and end with the block (twin.processes)
    with worker_pool(workers, initializer=_init_worker, initargs=(base, commands, names)) as pool:

        def evaluate(xs: list[NDArray]) -> list[Replay]:
            nonlocal evaluations
            todo = list(dict.fromkeys(_key(x) for x in xs if _key(x) not in cache))
            for key, result in zip(todo, pool.map(_replay_x, todo), strict=True):
                cache[key] = result
            evaluations += len(todo)
            if progress is not None:
                progress(evaluations, time.perf_counter() - started)
            return [cache[_key(x)] for x in xs]

        def cost(xs: list[NDArray]) -> list[float]:
            return [float(np.sum(residuals(measured, r) ** 2)) for r in evaluate(xs)]

        def zoom(x: NDArray, i: int, stages: int, span: float | None) -> NDArray:
            """Coarse-to-fine grid search of coordinate i (span None: its whole bound), each stage's
            candidates replayed in parallel."""
            a, b = (lo[i], hi[i]) if span is None else (max(lo[i], x[i] - span), min(hi[i], x[i] + span))
            best, best_cost = x, cost([x])[0]
            for _ in range(stages):
                grid = np.linspace(a, b, ZOOM_POINTS)
                xs = [np.where(np.arange(len(x)) == i, g, best) for g in grid]
                costs = cost(xs)
                k = int(np.argmin(costs))
                if costs[k] < best_cost:
                    best, best_cost = xs[k], costs[k]
                step = grid[1] - grid[0]
                a, b = max(lo[i], best[i] - step), min(hi[i], best[i] + step)
            return best

        def moved(x: NDArray, i: int, sign: int) -> NDArray:
            out = x.copy()
            n = names[i]
            out[i] += math.log(1 + sign * PROBE) if n in LOG_PARAMS else sign * PROBE * x[i]
            out[i] = np.clip(out[i], lo[i], hi[i])
            return out

        x = np.clip(np.array([math.log(start[n]) if n in LOG_PARAMS else start[n] for n in names]), lo, hi)
        x_initial = x.copy()
        # The sum of squares has narrow valleys (first contact and breakaway shift with the foam): a
        # gradient method alone lands on their walls. Grid-zoom the modulus first.
        ie = names.index("young_pa") if "young_pa" in names else None
        if ie is not None:
            scan = start_from == "scan"
            x = zoom(x, ie, stages=4 if scan else 3, span=None if scan else ZOOM_SPAN["young_pa"])
        # Each other parameter: is it identifiable once the modulus may follow it (a profile)? The
        # Poisson ratio mostly trades off against the modulus along a valley; a parameter that does
        # not raise the profile by IDENTIFIABLE_RMS_RISE stays at the run's description.
        free = [] if ie is None else [ie]
        rise: dict[str, float] = {}
        for i, n in enumerate(names):
            if i == ie:
                continue
            best = cost([x])[0]
            profile = []
            for sign in (1, -1):
                xp = moved(x, i, sign)
                if ie is not None:
                    xp = zoom(xp, ie, stages=2, span=PROFILE_SPAN)
                profile.append(cost([xp])[0])
            rise[n] = math.sqrt(min(profile) / max(best, 1e-12)) - 1.0
            if rise[n] >= IDENTIFIABLE_RMS_RISE:
                free.append(i)
                x = zoom(x, i, stages=3, span=ZOOM_SPAN[n])
                if ie is not None:
                    x = zoom(x, ie, stages=2, span=PROFILE_SPAN)

        def full(z: NDArray) -> NDArray:
            out = x.copy()
            out[free] = z
            return out

        def fun(z: NDArray) -> NDArray:
            return residuals(measured, evaluate([full(z)])[0])

        def jac(z: NDArray) -> NDArray:
            steps = [
                z + FD_STEP * np.eye(len(z))[j] * (1 if z[j] + FD_STEP <= hi[free][j] else -1)
                for j in range(len(z))
            ]
            base_r = fun(z)
            cols = [
                (residuals(measured, r) - base_r) / (s - z).sum()
                for r, s in zip(evaluate([full(s) for s in steps]), steps, strict=True)
            ]
            return np.column_stack(cols)

        sol = least_squares(
            fun,
            x[free],
            jac=jac,
            bounds=(lo[free], hi[free]),
            x_scale=1.0,
            max_nfev=POLISH_EVALUATIONS,
            xtol=1e-4,
        )
        x = full(sol.x)
        best = max(float(np.sum(sol.fun**2)), 1e-12)
        if ie is not None:
            rise["young_pa"] = math.sqrt(min(cost([moved(x, ie, 1), moved(x, ie, -1)])) / best) - 1.0
        sim_initial = evaluate([x_initial])[0]
        sim_fitted = evaluate([x])[0]

    fitted = _to_params(x, names)
    dof = max(len(sol.fun) - len(free), 1)
    cov = np.sum(sol.fun**2) / dof * np.linalg.pinv(sol.jac.T @ sol.jac)
    sigma = dict.fromkeys(names, float("nan"))
    for j, i in enumerate(free):
        s_i = math.sqrt(max(cov[j, j], 0.0))
        sigma[names[i]] = fitted[names[i]] * s_i if names[i] in LOG_PARAMS else s_i
    return FitResult(
        run_path=run.path,
        names=names,
        initial=_to_params(x_initial, names),
        fitted=fitted,
        sigma=sigma,
        sensitivity=rise,
        start_from=start_from,
        identifiable={n: bool(rise[n] >= IDENTIFIABLE_RMS_RISE) for n in names},
        held=[names[i] for i in range(len(names)) if i not in free],
        rms_initial=rms_by_channel(measured, sim_initial),
        rms_fitted=rms_by_channel(measured, sim_fitted),
        evaluations=evaluations,
        wall_s=time.perf_counter() - started,
        window_s=window,
        twin_truth=truth,
        measured=measured,
        sim_initial=sim_initial,
        sim_fitted=sim_fitted,
    )
