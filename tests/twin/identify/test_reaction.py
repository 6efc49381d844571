"""The reaction-model estimators recover known parameters from noisy data and refuse data that
cannot support a fit."""

import numpy as np
import pytest

from twin.identify.reaction import IdentificationError, fit_hunt_crossley, fit_kelvin_voigt, fit_reaction


def _cycles(n: int = 600, rng_seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.random.Generator]:
    t = np.arange(n) / 30.0
    delta = 0.004 + 0.0015 * np.sin(2 * np.pi * 0.5 * t)  # m: a 4 mm grasp with 1.5 mm cycles
    rate = np.gradient(delta, t)
    return delta, rate, np.random.default_rng(rng_seed)


def test_kelvin_voigt_recovers_stiffness_damping_and_preload():
    delta, rate, rng = _cycles()
    r = 0.4 + 2500.0 * delta + 30.0 * rate + rng.normal(0, 0.05, delta.size)
    fit = fit_kelvin_voigt(delta, rate, r)
    assert fit.params["k_n_m"] == pytest.approx(2500.0, rel=0.02)
    assert fit.params["c_ns_m"] == pytest.approx(30.0, abs=4 * fit.sigma["c_ns_m"])
    assert fit.params["r0_n"] == pytest.approx(0.4, abs=4 * fit.sigma["r0_n"])
    assert fit.rms_n == pytest.approx(0.05, rel=0.15) and fit.r2 > 0.99
    assert np.allclose(fit.predict(delta, rate), r, atol=0.25)


def test_hunt_crossley_recovers_the_exponent_of_a_stiffening_foam():
    delta, rate, rng = _cycles()
    r = 4e5 * (delta - 0.001) ** 1.5 * (1 + 0.8 * rate) + rng.normal(0, 0.01, delta.size)
    fit = fit_hunt_crossley(delta, rate, r)
    assert fit.params["n"] == pytest.approx(1.5, abs=0.1)
    assert fit.params["delta0_m"] == pytest.approx(0.001, abs=3e-4)
    assert fit.r2 > 0.99
    # The linear model misses the curvature that Hunt-Crossley captures.
    assert fit_kelvin_voigt(delta, rate, r).rms_n > 2 * fit.rms_n


@pytest.mark.parametrize(
    ("delta", "message"),
    [(np.full(5, 0.003), "only 5 samples"), (np.full(50, 0.003), "did not move")],
)
def test_data_that_cannot_support_a_fit_is_refused_in_one_line(delta, message):
    with pytest.raises(IdentificationError, match=message):
        fit_kelvin_voigt(delta, np.zeros_like(delta), np.ones_like(delta))


def test_unknown_model_names_the_choices():
    delta, rate, _ = _cycles(60)
    with pytest.raises(IdentificationError, match="kelvin-voigt, hunt-crossley"):
        fit_reaction("maxwell", delta, rate, delta)
