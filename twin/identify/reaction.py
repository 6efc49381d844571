"""Object reaction models R(delta, delta_dot) of one fingertip, fitted by least squares.

delta is the fingertip's travel into the object along its pad normal (m), measured from the pose
where the finger first touched (twin.identify.signals); delta_dot its rate (m/s).

- Kelvin-Voigt: R = R0 + k delta + c delta_dot. Linear in its parameters; k is the tangent
  stiffness about the grasp, R0 the preload's intercept.
- Hunt-Crossley: R = k (delta - delta0)^n (1 + lam delta_dot), delta0 a free contact onset: the
  nonlinear spring of foams that stiffen as they are crushed, with damping that vanishes at contact.

Uncertainties are 1-sigma from the least-squares covariance, s^2 (J^T J)^-1, with s^2 the residual
variance; they describe the fit; the modulus is inferred by twin.sim.modulus.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from twin.interface.errors import TwinError

MODELS = ("kelvin-voigt", "hunt-crossley")


class IdentificationError(TwinError, ValueError):
    """The data cannot support the fit (too few samples in contact, no excitation); one line."""


@dataclass(frozen=True)
class ReactionFit:
    """One finger's fitted reaction model."""

    model: str
    params: dict[str, float]
    sigma: dict[str, float]
    units: dict[str, str]
    rms_n: float
    r2: float
    samples: int

    def predict(self, delta_m: NDArray[np.float64], rate_m_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """R (N) at the given indentations and rates."""
        return predict(self.model, self.params, delta_m, rate_m_s)

    def to_json(self) -> dict:
        """Plain-JSON form for the results file."""
        return {
            "model": self.model,
            "params": self.params,
            "sigma": self.sigma,
            "units": self.units,
            "rms_n": self.rms_n,
            "r2": self.r2,
            "samples": self.samples,
        }


def predict(model: str, params: dict[str, float], delta_m: NDArray, rate_m_s: NDArray) -> NDArray[np.float64]:
    """R (N) of a model with the given parameters."""
    d = np.asarray(delta_m, dtype=float)
    v = np.asarray(rate_m_s, dtype=float)
    if model == "kelvin-voigt":
        return params["r0_n"] + params["k_n_m"] * d + params["c_ns_m"] * v
    x = np.clip(d - params["delta0_m"], 0.0, None)
    return params["k_n_mn"] * x ** params["n"] * (1.0 + params["lam_s_m"] * v)


def _check(delta_m: NDArray, reaction_n: NDArray) -> None:
    if len(delta_m) < 10:
        raise IdentificationError(f"only {len(delta_m)} samples in contact; the fit needs >= 10")
    if np.ptp(delta_m) < 1e-5:
        raise IdentificationError(
            "the fingertip did not move while in contact (< 0.01 mm): nothing to identify"
        )


def fit_kelvin_voigt(delta_m: NDArray, rate_m_s: NDArray, reaction_n: NDArray) -> ReactionFit:
    """Linear least squares R = R0 + k delta + c delta_dot."""
    d, v, y = (np.asarray(a, dtype=float) for a in (delta_m, rate_m_s, reaction_n))
    _check(d, y)
    a = np.column_stack([np.ones_like(d), d, v])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    residual = y - a @ coef
    dof = max(len(y) - 3, 1)
    cov = residual @ residual / dof * np.linalg.pinv(a.T @ a)
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    names = ("r0_n", "k_n_m", "c_ns_m")
    return ReactionFit(
        model="kelvin-voigt",
        params=dict(zip(names, map(float, coef), strict=True)),
        sigma=dict(zip(names, map(float, sig), strict=True)),
        units={"r0_n": "N", "k_n_m": "N/m", "c_ns_m": "N*s/m"},
        rms_n=float(np.sqrt(np.mean(residual**2))),
        r2=_r2(y, residual),
        samples=len(y),
    )


def fit_hunt_crossley(delta_m: NDArray, rate_m_s: NDArray, reaction_n: NDArray) -> ReactionFit:
    """Nonlinear least squares R = k (delta - delta0)^n (1 + lam delta_dot), n in [1, 3]."""
    from scipy.optimize import least_squares  # 0.3 s to import: only when this model is asked for

    d, v, y = (np.asarray(a, dtype=float) for a in (delta_m, rate_m_s, reaction_n))
    _check(d, y)
    kv = fit_kelvin_voigt(d, v, y)
    k_lin = max(kv.params["k_n_m"], 1.0)
    # start from the linear spring: onset where the Kelvin-Voigt line crosses zero, n = 1
    delta0 = float(np.clip(-kv.params["r0_n"] / k_lin, d.min() - 0.05, d.min() - 1e-6))
    scale_d = max(float(np.ptp(d)), 1e-4)

    def model(p: NDArray) -> NDArray:
        log_k, n, lam, d0 = p
        x = np.clip((d - d0) / scale_d, 1e-9, None)
        return np.exp(log_k) * x**n * (1.0 + lam * v)

    x0 = np.array([np.log(k_lin * (d.mean() - delta0)), 1.0, 0.0, delta0])
    lower = [-np.inf, 1.0, -50.0, d.min() - 0.1]
    upper = [np.inf, 3.0, 50.0, d.min() - 1e-6]
    x0 = np.clip(x0, np.array(lower) + 1e-9, np.array(upper) - 1e-9)
    sol = least_squares(lambda p: model(p) - y, x0, bounds=(lower, upper), x_scale="jac")
    residual = sol.fun
    dof = max(len(y) - 4, 1)
    cov = residual @ residual / dof * np.linalg.pinv(sol.jac.T @ sol.jac)
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    log_k, n, lam, d0 = sol.x
    k = float(np.exp(log_k) / scale_d**n)  # back to N/m^n
    return ReactionFit(
        model="hunt-crossley",
        params={"k_n_mn": k, "n": float(n), "lam_s_m": float(lam), "delta0_m": float(d0)},
        sigma={
            "k_n_mn": float(k * sig[0]),
            "n": float(sig[1]),
            "lam_s_m": float(sig[2]),
            "delta0_m": float(sig[3]),
        },
        units={"k_n_mn": "N/m^n", "n": "1", "lam_s_m": "s/m", "delta0_m": "m"},
        rms_n=float(np.sqrt(np.mean(residual**2))),
        r2=_r2(y, residual),
        samples=len(y),
    )


def fit_reaction(model: str, delta_m: NDArray, rate_m_s: NDArray, reaction_n: NDArray) -> ReactionFit:
    """Fit the named model (one of MODELS)."""
    if model == "kelvin-voigt":
        return fit_kelvin_voigt(delta_m, rate_m_s, reaction_n)
    if model == "hunt-crossley":
        return fit_hunt_crossley(delta_m, rate_m_s, reaction_n)
    raise IdentificationError(f"unknown reaction model '{model}' (choose from {', '.join(MODELS)})")


def _r2(y: NDArray, residual: NDArray) -> float:
    var = float(np.var(y))
    return float(1.0 - np.var(residual) / var) if var > 0 else float("nan")
