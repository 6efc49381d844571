"""The hand's side of eq. 4, identified per finger from a free-motion run (no object, R = 0).

With nothing touching the fingertip the strain gauge reads the torque that moves the outer link:
  tau = I theta_ddot + b theta_dot + f_c tanh(theta_dot / w) + g_c cos(phi) + g_s sin(phi) + tau_0,
inertia I, viscous damping b, Coulomb friction f_c (smoothed over w), gravity through the link's
absolute angle phi (inner + outer, palm-up hand) and the gauge's zero offset tau_0. Linear in the
parameters, so ordinary least squares; derivatives by Gaussian derivative filters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from twin.identify.signals import FingerSignals

TERMS = ("inertia_kgm2", "damping_nms", "friction_nm", "gravity_cos_nm", "gravity_sin_nm", "offset_nm")
UNITS = {"inertia_kgm2": "kg*m^2", "damping_nms": "N*m*s", "friction_nm": "N*m"} | {
    t: "N*m" for t in TERMS[3:]
}
FRICTION_SMOOTHING_RAD_S = 0.05
"""w of the tanh friction: below ~0.05 rad/s the friction torque fades in (avoids a sign jump)."""
SMOOTHING_SAMPLES = 2.0
"""Gaussian sigma of the derivative filters (67 ms at 30 Hz): smooths encoder steps, keeps 0.5 Hz motion."""


def derivatives(t_s: NDArray, angle_rad: NDArray) -> tuple[NDArray, NDArray]:
    """(n, k) first and second time derivatives by Gaussian derivative filters on a uniform clock."""
    dt = float(np.median(np.diff(t_s)))
    x = np.asarray(angle_rad, dtype=float)
    return _gaussian_derivative(x, 1) / dt, _gaussian_derivative(x, 2) / dt**2


def _gaussian_derivative(x: NDArray, order: int) -> NDArray:
    """Convolve each column with the order-th derivative of a Gaussian (edges held), in samples.

    What scipy.ndimage.gaussian_filter1d(order=...) computes; done in numpy because importing
    scipy.ndimage costs 0.2-0.4 s of `twin identify`'s 2 s budget."""
    sigma = SMOOTHING_SAMPLES
    half = int(4 * sigma + 0.5)
    u = np.arange(-half, half + 1, dtype=float)
    g = np.exp(-0.5 * (u / sigma) ** 2)
    g /= g.sum()
    kernel = u / sigma**2 * g if order == 1 else (u**2 / sigma**4 - 1 / sigma**2) * g  # correlation kernels
    padded = np.pad(x, [(half, half)] + [(0, 0)] * (x.ndim - 1), mode="edge")
    cols = padded.reshape(len(padded), -1)
    out = np.column_stack([np.convolve(c, kernel[::-1], mode="valid") for c in cols.T])
    return out.reshape(x.shape)


def regressors(outer_rad: NDArray, vel: NDArray, acc: NDArray, link_abs_rad: NDArray) -> NDArray:
    """(n, 6) columns of the linear model, in TERMS order, for one finger."""
    return np.column_stack(
        [
            acc,
            vel,
            np.tanh(vel / FRICTION_SMOOTHING_RAD_S),
            np.cos(link_abs_rad),
            np.sin(link_abs_rad),
            np.ones_like(outer_rad),
        ]
    )


@dataclass(frozen=True)
class HandDynamics:
    """Identified hand terms of eq. 4, per finger (F1-F3)."""

    params: list[dict[str, float]]
    sigma: list[dict[str, float]]
    rms_nm: list[float]
    source: str
    """Where the terms came from: a free-motion run's path, or 'zero' when none was given."""

    def torque_nm(self, signals: FingerSignals) -> NDArray[np.float64]:
        """(n, 3) the hand's own torque (left side of eq. 4 less tau) along a run's motion."""
        vel, acc = derivatives(signals.t_s, signals.outer_rad)
        out = np.zeros_like(signals.outer_rad)
        for k in range(3):
            a = regressors(signals.outer_rad[:, k], vel[:, k], acc[:, k], signals.link_abs_rad[:, k])
            out[:, k] = a @ np.array([self.params[k][t] for t in TERMS])
        return out

    def to_json(self) -> dict:
        """Plain-JSON form for the results file."""
        return {
            "source": self.source,
            "units": UNITS,
            "fingers": [
                {"finger": k + 1, "params": self.params[k], "sigma": self.sigma[k], "rms_nm": self.rms_nm[k]}
                for k in range(3)
            ],
        }

    @classmethod
    def zero(cls) -> HandDynamics:
        """Every hand term zero."""
        zeros = [dict.fromkeys(TERMS, 0.0) for _ in range(3)]
        return cls(
            params=zeros,
            sigma=[dict.fromkeys(TERMS, float("nan")) for _ in range(3)],
            rms_nm=[0.0] * 3,
            source="zero",
        )


def identify_hand(signals: FingerSignals) -> HandDynamics:
    """Least squares of the strain-gauge torque on the hand terms over a free-motion run."""
    vel, acc = derivatives(signals.t_s, signals.outer_rad)
    params, sigma, rms = [], [], []
    for k in range(3):
        a = regressors(signals.outer_rad[:, k], vel[:, k], acc[:, k], signals.link_abs_rad[:, k])
        y = signals.torque_nm[:, k]
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        residual = y - a @ coef
        cov = residual @ residual / max(len(y) - a.shape[1], 1) * np.linalg.pinv(a.T @ a)
        params.append(dict(zip(TERMS, map(float, coef), strict=True)))
        sigma.append(dict(zip(TERMS, map(float, np.sqrt(np.clip(np.diag(cov), 0, None))), strict=True)))
        rms.append(float(np.sqrt(np.mean(residual**2))))
    return HandDynamics(params=params, sigma=sigma, rms_nm=rms, source=str(signals.run_path))
