"""The identification interval's calibration (benchmarks/interval_calibration.py) against its data and
against the normal distribution's known quantile."""

import math

import numpy as np
import pytest

from benchmarks import interval_calibration as cal
from twin.sim.modulus import INTERVAL_SCALE, Z95


def test_the_modulus_interval_is_scaled_by_the_conformal_quantile_of_its_calibration_runs():
    """twin.sim.modulus.INTERVAL_SCALE is what its calibration data give (to its 3 decimals), and on those
    runs it covers at least the nominal 95 %, as split conformal prediction guarantees in-sample."""
    rows = cal.load()
    assert len(rows) >= 40 and {r["shape"] for r in rows} == {"block", "cylinder", "sphere", "egg", "bumpy"}
    score = cal.scores(rows)
    assert INTERVAL_SCALE == pytest.approx(cal.conformal_quantile(score) / Z95, abs=5e-4)
    assert np.mean(score <= INTERVAL_SCALE * Z95) >= 0.95


def test_the_conformal_quantile_of_gaussian_scores_is_the_normal_quantile():
    """|z| of standard normal errors: the 95 % conformal quantile tends to 1.96 (the scale a calibrated
    Gaussian interval needs is 1), and on a small sample it is the ceil(0.95 (n + 1))-th smallest."""
    z = np.abs(np.random.default_rng(3).standard_normal(200_000))
    assert cal.conformal_quantile(z) == pytest.approx(Z95, abs=0.02)
    assert cal.conformal_quantile(np.arange(1.0, 20.0)) == 19.0  # rank ceil(0.95 * 20) = 19 of 19
    assert cal.conformal_quantile(np.arange(1.0, 40.0)) == 38.0  # rank ceil(0.95 * 40) = 38 of 39
    assert cal.conformal_quantile(np.arange(1.0, 18.0)) == math.inf  # 17 scores cannot promise 95 %


def test_a_score_is_the_error_in_units_of_the_interval_sigma_before_calibration():
    """A run drawn with a calibrated interval is undone of its scale: the same run scored either way."""
    raw = {"true_young_pa": 1e5, "estimate_pa": 1.1e5, "interval_scale": 1.0}
    raw |= {"ci95_low_pa": 1.1e5 * math.exp(-0.2), "ci95_high_pa": 1.1e5 * math.exp(0.2)}
    scaled = raw | {
        "interval_scale": 0.5,
        "ci95_low_pa": 1.1e5 * math.exp(-0.1),
        "ci95_high_pa": 1.1e5 * math.exp(0.1),
    }
    expected = math.log(1.1) / (0.2 / Z95)
    assert cal.scores([raw, scaled]) == pytest.approx([expected, expected])
