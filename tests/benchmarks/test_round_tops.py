"""The round-top benchmark's k at the deepest depth (benchmarks/round_tops.py), on the shipped sphere."""

from __future__ import annotations

import pytest

from benchmarks import round_tops


def test_the_deepest_depths_k_matches_the_fem_there_and_rests_on_a_force_proportional_to_k():
    entry = round_tops._shipped_sphere()
    k6, residual = round_tops.deepest_k(entry)
    assert residual[-1] == pytest.approx(0.0, abs=1e-12)
    assert residual[0] > 0.5 and k6 > entry["k"]  # Hertz-like FEM: flex too stiff shallow, soft deep
    # The premise, from the fit's own rounds: the flex's force scales with k near the fit (within 1 %).
    (k_a, f_a), (k_b, f_b) = ((r["k"], r["force_n"]) for r in entry["fit_rounds"][-2:])
    for a, b in zip(f_a, f_b, strict=True):
        assert b / a == pytest.approx(k_b / k_a, rel=0.01)
