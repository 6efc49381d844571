"""benchmarks/grasp_scatter.py measures what it says: how far apart grasps lie, and how much of the
placement's effect a term linear in it carries."""

import math

import numpy as np
import pytest

from benchmarks import grasp_scatter


def test_shares_apart_is_the_largest_distance_between_two_grasps_held():
    run = [0.34, 0.33, 0.33]
    thumb_off = [0.49, 0.48, 0.03]  # a grasp whose thumb pad barely touches
    farthest = [0.32, 0.33, 0.35]  # from thumb_off: 0.17, 0.15, 0.32 apart
    shares = np.array([run, farthest, thumb_off, [math.nan] * 3])  # the last not held: left out
    expected = math.sqrt(0.17**2 + 0.15**2 + 0.32**2)
    assert grasp_scatter.shares_apart(shares) == pytest.approx(expected)
    assert math.isnan(grasp_scatter.shares_apart(np.array([run, [math.nan] * 3])))


def test_an_effect_even_in_x_is_carried_by_x_squared_not_by_a_linear_term():
    """An object off centre along x either way moves ln S alike (F1 and F2 mirror each other): x and y
    explain almost none of it, x^2 all of it; an effect linear in y is explained either way."""
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-3.0, 3.0, (2, 40))
    linear, with_x2 = grasp_scatter.placement_r2(x, y, 0.01 * x**2)
    assert linear < 0.1 and with_x2 == pytest.approx(1.0)
    linear, with_x2 = grasp_scatter.placement_r2(x, y, 0.01 * y)
    assert linear == pytest.approx(1.0) and with_x2 == pytest.approx(1.0)
