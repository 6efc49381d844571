"""Real-to-sim: the twin's foam parameters that make replays of a run reproduce its measurements.

Rollout-based least squares: each candidate (Young's modulus, elasticity damping, Poisson ratio) is
a replay of the run's recorded commands (twin.sim.replay); the residuals are the measured minus the
replayed finger counts, distal torques and fingertip forces, each scaled by its sensor's resolution.
The sum of squares has narrow valleys (first contact and breakaway move with the foam), so the
search is a coarse-to-fine grid per parameter (modulus over its whole range first), then scipy's
trust-region least squares polishes all parameters together. Every batch of candidates (a grid
stage, a finite-difference Jacobian) is replayed in parallel processes: the clutch runs in Python
between steps, so mujoco.rollout's native threads cannot run this model.

Identifiability is judged by replaying, not by the formal covariance (the residuals are not white:
first-contact timing and stick-slip make them so): a parameter moved 25 % either way from its fit
must raise the residual RMS by IDENTIFIABLE_RMS_RISE, or it is reported as not identifiable from
the run. The fit still returns it, but it means little.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from twin.interface.devices import TAXEL_COUNT_MAX
from twin.interface.errors import ConfigError
from twin.recording.reader import Run
from twin.sim.foam import FoamParams
from twin.sim.replay import Commands, Replay, replay
from twin.tactile.layout import FINGERTIP_PADS, LAYOUT

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
PROBE = 0.25
"""Relative move of each fitted parameter in the identifiability probe."""
IDENTIFIABLE_RMS_RISE = 0.05
"""A 25 % move must raise the residual RMS by 5 % for the parameter to count as identified."""
START = {"young_pa": 4e4, "damping": 0.004, "poisson": 0.25}
"""Generic foam guesses, never the run's own values (on a sim run those are the truth being tested).
The modulus is scanned over its range before the search unless an initial value is given."""
FD_STEP = 0.01
"""Finite-difference step of the final polish, in search coordinates (1 % of a log parameter)."""


class FitError(ConfigError):
    """The run cannot be fitted (not a sim-describable run, no commands, nothing to fit)."""


def _identified_young_pa(path: Path) -> float | None:
    """E from `twin identify` (eq. 4 and the material mapping), or None where it cannot say."""
    from twin.identify.identify import identify_run

    try:
        material = identify_run(path).material
    except (ValueError, KeyError):  # no tactile, no compress phase, nothing to identify: scan instead
        return None
    return None if material is None or material["extrapolated"] else float(material["young_pa"])


def foam_of_run(run: Run) -> FoamParams:
    """The foam described by the run's metadata (or the researcher's shape and size on hardware)."""
    obj = run.metadata.get("object")
    if not obj:
        raise FitError(f"{run.path}: the run does not describe its object; nothing to put in the twin")
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


def _to_params(x: Sequence[float], names: Sequence[str]) -> dict[str, float]:
    return {n: (math.exp(v) if n in LOG_PARAMS else float(v)) for n, v in zip(names, x, strict=True)}


def _replay_x(x: Sequence[float]) -> Replay:
    params = _to_params(x, _WORKER["names"])
    return replay(_WORKER["base"].with_overrides(**params), _WORKER["commands"])


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
) -> FitResult:
    """Fit the named foam parameters of the twin to a recorded run."""
    started = time.perf_counter()
    run = Run(run_path)
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
    base = foam_of_run(run)
    window = fit_window_s(run)
    commands = Commands.from_run(run, until_s=window)
    measured = Measured.from_run(run, commands)
    start = {n: START[n] for n in names} | (initial or {})
    start_from = "given" if "young_pa" in (initial or {}) else "scan"
    if "young_pa" in names and start_from == "scan":
        identified = _identified_young_pa(run.path)  # twin identify's estimate, when the mapping covers it
        if identified is not None:
            start["young_pa"], start_from = identified, "identify"
    truth = {n: getattr(base, n) for n in names} if run.metadata.get("backend") == "sim" else {}
    lo = np.array([math.log(BOUNDS[n][0]) if n in LOG_PARAMS else BOUNDS[n][0] for n in names])
    hi = np.array([math.log(BOUNDS[n][1]) if n in LOG_PARAMS else BOUNDS[n][1] for n in names])
    cache: dict[tuple[float, ...], Replay] = {}
    evaluations = 0

    with ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(base, commands, names)) as pool:

        def evaluate(xs: list[NDArray]) -> list[Replay]:
            nonlocal evaluations
            todo = [tuple(np.round(x, 12)) for x in xs if tuple(np.round(x, 12)) not in cache]
            for key, result in zip(todo, pool.map(_replay_x, todo), strict=True):
                cache[key] = result
            evaluations += len(todo)
            if progress is not None:
                progress(evaluations, time.perf_counter() - started)
            return [cache[tuple(np.round(x, 12))] for x in xs]

        x0 = np.array([math.log(start[n]) if n in LOG_PARAMS else start[n] for n in names])
        x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
        x_initial = x0.copy()

        def cost(xs: list[NDArray]) -> list[float]:
            return [float(np.sum(residuals(measured, r) ** 2)) for r in evaluate(xs)]

        def zoom(x: NDArray, i: int, stages: int, points: int, full: bool) -> NDArray:
            """Coarse-to-fine grid search of coordinate i, the grid's points replayed in parallel."""
            a, b = (
                (lo[i], hi[i])
                if full
                else (max(lo[i], x[i] - ZOOM_SPAN[names[i]]), min(hi[i], x[i] + ZOOM_SPAN[names[i]]))
            )
            best, best_cost = x, cost([x])[0]
            for _ in range(stages):
                grid = np.linspace(a, b, points)
                xs = [np.where(np.arange(len(x)) == i, g, best) for g in grid]
                costs = cost(xs)
                k = int(np.argmin(costs))
                if costs[k] < best_cost:
                    best, best_cost = xs[k], costs[k]
                step = grid[1] - grid[0]
                a, b = max(lo[i], best[i] - step), min(hi[i], best[i] + step)
            return best

        # The objective has narrow valleys (first contact and breakaway shift with the foam), so a
        # gradient method alone lands on their walls: grid-zoom each parameter, the modulus first
        # and again after the others, then polish all together.
        x = x0
        order = [n for n in ("young_pa", "poisson", "young_pa", "damping") if n in names]
        if order.count("young_pa") == 2 and len(set(order)) == 1 + ("damping" in order):
            order.remove("young_pa")  # the second modulus pass only re-centres after the Poisson ratio
        for pass_no, n in enumerate(order):
            i = names.index(n)
            first_e = n == "young_pa" and pass_no == 0 and start_from == "scan"
            x = zoom(x, i, stages=4 if first_e else 3, points=ZOOM_POINTS, full=first_e)

        def fun(x: NDArray) -> NDArray:
            return residuals(measured, evaluate([x])[0])

        def jac(x: NDArray) -> NDArray:
            steps = [
                x + FD_STEP * np.eye(len(x))[i] * (1 if x[i] + FD_STEP <= hi[i] else -1)
                for i in range(len(x))
            ]
            base_r = fun(x)
            cols = [
                (residuals(measured, r) - base_r) / (s - x).sum()
                for r, s in zip(evaluate(steps), steps, strict=True)
            ]
            return np.column_stack(cols)

        sol = least_squares(
            fun,
            x,
            jac=jac,
            bounds=(lo, hi),
            x_scale=1.0,
            diff_step=None,
            max_nfev=POLISH_EVALUATIONS,
            xtol=1e-4,
        )
        probes = []
        for i, n in enumerate(names):
            for sign in (1, -1):
                step = math.log(1 + sign * PROBE) if n in LOG_PARAMS else sign * PROBE * sol.x[i]
                probes.append(sol.x + step * np.eye(len(names))[i])
        probe_cost = [float(np.sum(residuals(measured, r) ** 2)) for r in evaluate([x_initial, *probes])[1:]]
        sim_initial = evaluate([x_initial])[0]
        sim_fitted = evaluate([sol.x])[0]

    fitted = _to_params(sol.x, names)
    dof = max(len(sol.fun) - len(names), 1)
    cov = np.sum(sol.fun**2) / dof * np.linalg.pinv(sol.jac.T @ sol.jac)
    sig_x = np.sqrt(np.clip(np.diag(cov), 0, None))
    sigma = {
        n: float(fitted[n] * s) if n in LOG_PARAMS else float(s) for n, s in zip(names, sig_x, strict=True)
    }
    best = max(float(np.sum(sol.fun**2)), 1e-12)
    rise = {
        n: math.sqrt(min(probe_cost[2 * i], probe_cost[2 * i + 1]) / best) - 1.0 for i, n in enumerate(names)
    }
    return FitResult(
        run_path=run.path,
        names=names,
        initial=_to_params(x_initial, names),
        fitted=fitted,
        sigma=sigma,
        sensitivity=rise,
        start_from=start_from,
        identifiable={n: bool(rise[n] >= IDENTIFIABLE_RMS_RISE) for n in names},
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
