"""The identification interval's calibration (benchmarks/interval_calibration.py) against its data and
against the normal distribution's known quantile."""

import math

import numpy as np
import pytest

from benchmarks import interval_calibration as cal
from twin.sim.modulus import INTERVAL_SCALE, Z95


def test_the_interval_scale_shipped_covers_the_recorded_hidden_runs_at_their_nominal_rate():
    """twin.sim.modulus.INTERVAL_SCALE holds the truth in at least 95 % of the recorded hidden runs, and
    in at least 90 % of every draw's (the issue's bar): a smaller scale, which the median error invites,
    is refused by the draws it failed on."""
    rows = cal.load()
    assert len(rows) >= 100 and {r["shape"] for r in rows} == {"block", "cylinder", "sphere", "egg", "bumpy"}
    assert np.mean(cal.scores(rows) <= INTERVAL_SCALE * Z95) >= 0.95
    for draw in {r["draw"] for r in rows}:
        these = cal.score_draw([r for r in rows if r["draw"] == draw], INTERVAL_SCALE)
        assert these["covered"] >= 0.9 * these["runs"], (draw, these)
    assert cal.score_draw(rows, 0.585)["covered"] < 0.95 * len(rows)  # the first calibration's, refused


def test_prequential_scoring_calibrates_each_draw_on_the_ones_before_it():
    """The benchmark section: the first draw has nothing before it; each later one is scored at the
    conformal scale of those before, which for 2040 and 2041 were the scales they were run with."""
    results = cal.run()
    draws = results["draws"]
    assert "prequential" not in draws[0] and all("prequential" in d for d in draws[1:])
    for d in draws[1:]:
        if d["run_scale"] != 1.0:
            assert d["prequential"]["scale"] == pytest.approx(d["run_scale"], abs=5e-4)
    assert "| 2041 |" in cal.to_markdown(results)


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
