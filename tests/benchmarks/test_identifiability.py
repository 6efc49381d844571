"""benchmarks/identifiability.py measures what it says: the floor's arithmetic, its conditions and the
features it reads off a real twin run."""

import json
import math

import numpy as np
import pytest
from twin.experiments.compress import run_compress

from benchmarks import identifiability
from twin.identify.identify import squeeze_stiffness
from twin.identify.signals import load_signals
from twin.sim.backend import SimBackend
from twin.sim.foam import get_object


def test_expected_beyond_counts_what_a_gaussian_estimator_puts_past_the_bar():
    rng = np.random.default_rng(0)
    sigmas = np.array([0.03, 0.07, 0.12])
    errors = rng.normal(0.0, 1.0, (200_000, 1)) * sigmas  # log E estimated minus true
    beyond = np.mean(np.abs(np.expm1(errors)) > identifiability.BOUND)
    assert identifiability.expected_beyond(sigmas) == pytest.approx(40 * beyond, rel=0.02)
    assert identifiability.expected_beyond(np.array([0.01])) < 1e-6  # a tight estimator never misses
    # a 95 % interval of exactly +-15 % in log E (+15 % reaches 1.96 sigma, -15 % 2.28): 3.6 % of runs miss
    at_bar = identifiability.expected_beyond(np.array([math.log1p(0.15) / identifiability.Z95]))
    assert at_bar == pytest.approx(40 * (0.025 + 0.0113), rel=0.01)


def test_read_floor_counts_only_the_simulations_that_grasp_as_the_run_did():
    rng = np.random.default_rng(1)
    log_e = np.log(40e3) + np.linspace(-0.5, 0.5, 16)
    log_s = 0.8 * log_e + 1.0 + rng.normal(0.0, 0.02, 16)
    run_shares = np.array([0.34, 0.33, 0.33])
    shares = np.tile(run_shares, (16, 1))
    other = np.arange(16) % 4 == 0  # a second branch: other shares, S 35 % higher
    log_s[other] += 0.3
    shares[other] = [0.45, 0.45, 0.10]
    truth = math.log(45e3)
    run = (0.8 * truth + 1.0, run_shares, truth)
    floor = identifiability.read_floor(log_e, log_s, shares, run)
    assert floor["power"] == pytest.approx(0.8, abs=0.05)
    assert floor["sigma"] == pytest.approx(0.02 / 0.8, rel=0.5)  # the like grasps' scatter, not the branch
    assert abs(floor["error"]) < 0.03
    shares[:] = run_shares  # the shares no longer tell the branch apart: the floor widens
    assert identifiability.read_floor(log_e, log_s, shares, run)["sigma"] > 2 * floor["sigma"]


def test_each_condition_sets_what_it_knows_to_the_truth():
    case = {
        "shape": "block",
        "young_pa": 50e3,
        "poisson": 0.31,
        "placement_m": (0.002, -0.001),
        "size_m": (0.06, 0.065, 0.07),
        "seed": 1,
    }
    drawn, place, size, everything = (
        identifiability.condition_foams(case, c, seed=3, k=8) for c in identifiability.CONDITIONS
    )
    young = [f.young_pa for f in drawn]
    assert young[0] == pytest.approx(50e3 / identifiability.SPREAD) and young[-1] == pytest.approx(85e3)
    assert len({f.placement_m for f in drawn}) == 8 and len({f.size_m for f in drawn}) == 8
    assert all(abs(v) <= 0.003 for f in drawn for v in f.placement_m)
    assert all(f.placement_m == case["placement_m"] for f in place + size + everything)
    assert len({f.size_m for f in place}) == 8
    assert all(f.size_m == pytest.approx(case["size_m"]) for f in size + everything)
    assert len({f.poisson for f in size}) == 8 and all(f.poisson == 0.31 for f in everything)


def test_run_features_of_a_twin_run(tmp_path):
    foam = get_object("sphere")
    run_compress(SimBackend(foam, seed=5), tmp_path / "run", duration_s=7.0, object_name=foam.name)
    features = identifiability.run_features(tmp_path / "run")
    assert len(features) == 50
    s, _, _ = squeeze_stiffness(load_signals(tmp_path / "run"), 3)
    assert features["log_s"] == pytest.approx(math.log(s))
    assert sum(features[f"f{k}_share"] for k in (1, 2, 3)) == pytest.approx(1.0)
    for k in (1, 2, 3):
        assert features[f"f{k}_contact"] == 1.0  # the library sphere is held on every fingertip
        assert features[f"f{k}_area_taxels"] >= 1
        assert 0.0 < features[f"f{k}_centre_x_mm"] < 60.0  # on the outer link, beyond the distal joint
    assert features["palm_force"] >= 0.0


def _square(job: tuple) -> tuple[float, np.ndarray] | None:
    """A stand-in simulation: S = x^2, shares (x, 1, 2); None for a dropped object (negative x)."""
    (x,) = job
    return None if x < 0 else (float(x * x), np.array([x, 1.0, 2.0]))


def test_the_floor_simulations_resume_where_a_stopped_call_left_them(tmp_path):
    """An hour of simulations stopped anywhere loses none that finished: each is kept as it ends, a cut
    last line is skipped (and computed again), and a later call reads the whole set back."""
    jobs = [(x,) for x in (3.0, -1.0, 2.0, 5.0)]
    kept = tmp_path / "simulations.json"
    partial = kept.with_suffix(".partial.jsonl")
    partial.write_text(
        '{"job": 0, "result": [9.0, [3.0, 1.0, 2.0]]}\n{"job": 1, "result": null}\n{"job": 3, "res'
    )
    calls: list[tuple] = []

    def counted(job: tuple) -> tuple[float, np.ndarray] | None:
        calls.append(job)
        return _square(job)

    def stopped(job: tuple) -> tuple[float, np.ndarray] | None:
        if job == (5.0,):
            raise KeyboardInterrupt  # stopped in the middle: job 2's result is already kept
        return counted(job)

    with pytest.raises(KeyboardInterrupt):
        identifiability.simulations_kept(stopped, jobs, kept, workers=1)
    assert [json.loads(line)["job"] for line in partial.read_text().splitlines()[-1:]] == [2]
    calls.clear()
    got = identifiability.simulations_kept(counted, jobs, kept, workers=1)
    assert calls == [(5.0,)]  # jobs 0, 1 and 2 were kept; 3's line was cut
    assert got[1] is None and [g[0] for g in (got[0], got[2], got[3])] == [9.0, 4.0, 25.0]
    assert np.array_equal(got[3][1], [5.0, 1.0, 2.0])
    assert kept.is_file() and not partial.exists()
    calls.clear()
    again = identifiability.simulations_kept(counted, jobs, kept, workers=1)
    assert calls == [] and again[1] is None and again[3][0] == 25.0
