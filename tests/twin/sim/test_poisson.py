"""The twin's cheap observation of the two-pair strains (cameras read at rest and at the troughs) reads
what a recorded run of the same twin reads: the grid of simulations and the run share one statistic."""

import argparse
from pathlib import Path

import pytest

from tests.once import made_once
from twin import api
from twin.cli.identify import _poisson
from twin.sim import poisson
from twin.sim.foam import LIBRARY
from twin.sim.modulus import Tolerances

TRUTH = poisson.twin_foam(LIBRARY["block"], 35e3, 0.3, (0.001, -0.002))
"""The fast block at E 35 kPa, nu 0.3, placed 1 mm / -2 mm off centre."""
SEED = 11


@pytest.fixture(scope="session")
def two_pair_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recorded two-pair compress run of TRUTH (its 30 fps stereo is the costly part: made once for
    both xdist workers, tests/once.py)."""

    def record(out: Path) -> None:
        backend = api.sim_backend(TRUTH, seed=SEED, cameras=True, camera_placements="lateral,opposite")
        api.compress(backend, duration_s=poisson.DURATION_S, out=out)

    return made_once(tmp_path_factory, "poisson-two-pair-run", record)


@pytest.mark.slow
def test_the_twins_observation_matches_a_recorded_two_pair_run(two_pair_run: Path):
    sparse = poisson.observe(TRUTH, seed=SEED)
    recorded = poisson.observe_recorded(two_pair_run, TRUTH)
    assert len(recorded.width_m) == len(sparse.width_m) == 2
    (ex_r, ez_r), (ex_s, ez_s) = recorded.strains(), sparse.strains()
    # The squeeze's strains (eps_x ~ +0.04, eps_z ~ -0.12): within a tenth of the noise taken for them
    # (twin.vision.lateral_strain.STRAIN_NOISE: 0.002, 0.003); the placement read within 0.1 mm in x.
    assert 0.02 < ex_r < 0.08 and -0.2 < ez_r < -0.05
    assert ex_s == pytest.approx(ex_r, abs=0.0005) and ez_s == pytest.approx(ez_r, abs=0.0005)
    assert sparse.centre_x_m == pytest.approx(recorded.centre_x_m, abs=1e-4)
    assert recorded.centre_x_m == pytest.approx(0.001, abs=5e-4)


@pytest.mark.slow
def test_a_recorded_two_pair_run_reads_its_poisson_ratio_through_the_twin(two_pair_run: Path):
    """`twin identify --poisson-from-cameras`'s read of nu (its own code: twin.cli.identify._poisson, on
    twin.sim.poisson.poisson_for_modulus and read_run) on a recorded two-pair run of the fast block at nu
    0.3, E 35 kPa, 1 mm / -2 mm off centre: nu's 95 % interval holds the truth and is under +-0.06 wide
    (the prior's range is +-0.075); the placement is read within 0.5 mm in x; the modulus simulations
    then draw the tolerance cut to the read's interval; the printout says whose nu it is."""
    args = argparse.Namespace(
        run_dir=two_pair_run, tolerances=Tolerances(), poisson_from_cameras=True, no_progress=True
    )
    notes: list[str] = []
    recorded = _poisson(args, LIBRARY["block"], notes)
    low, high = recorded["poisson_ci95_linearised"]
    assert low < 0.3 < high and high - low < 0.12, recorded
    assert recorded["placement_m"][0] == pytest.approx(0.001, abs=5e-4), recorded
    young_low, young_high = recorded["young_from_strains_ci95_pa"]
    assert young_low < recorded["young_from_strains_pa"] < young_high and recorded["simulations"] == 12
    # What the modulus simulations then draw: the tolerance cut to the read's interval (the same function
    # for the CLI and the camera benchmark).
    drawn = poisson.drawn_poisson_range((0.2, 0.35), (low, high))[0]
    assert recorded["narrowed"] and tuple(recorded["drawn_range"]) == drawn == args.tolerances.poisson
    assert 0.2 <= drawn[0] < 0.3 < drawn[1] <= 0.35
    # The results file's interval stays within the Poisson ratios the twin simulated, and says whether
    # the linearised read reached beyond them.
    assert recorded["poisson_ci95"] == [max(low, 0.2), min(high, 0.35)]
    assert recorded["poisson_ci95_beyond_simulated"] == (low < 0.2 or high > 0.35)
    assert recorded["reference"] == poisson.REFERENCE_CAVEAT
    assert any(poisson.REFERENCE_CAVEAT in n for n in notes), notes


def test_a_read_whose_interval_reaches_beyond_the_simulated_poisson_ratios_is_cut_to_them():
    """A flat strain-to-nu slope gives a linearised interval like -8 to 8.4 (seen on hidden draw 2043):
    the results file states nu within the simulated 0.2-0.35 instead, and that it was cut."""
    wide = poisson.PoissonRead(0.35, (-8.0, 8.4), 40e3, (30e3, 50e3), (0.0, 0.0), (0.04, -0.12), 12)
    assert wide.poisson_95_simulated() == ((0.2, 0.35), True)
    narrow = poisson.PoissonRead(0.3, (0.27, 0.33), 40e3, (30e3, 50e3), (0.0, 0.0), (0.04, -0.12), 12)
    assert narrow.poisson_95_simulated() == ((0.27, 0.33), False)
    above = poisson.PoissonRead(0.35, (0.38, 0.45), 40e3, (30e3, 50e3), (0.0, 0.0), (0.04, -0.12), 12)
    assert above.poisson_95_simulated() == ((0.35, 0.35), True)  # never an inverted interval
    assert wide.to_json()["poisson_ci95"] == [0.2, 0.35] and wide.to_json()["poisson_ci95_beyond_simulated"]
    # and says whose nu it is: the twin's (no reference here covers the grasp)
    assert wide.to_json()["reference"] == poisson.REFERENCE_CAVEAT


def test_the_cameras_interval_narrows_the_tolerated_poisson_range():
    assert poisson.drawn_poisson_range((0.2, 0.35), (0.26, 0.31)) == ((0.26, 0.31), None)
    assert poisson.drawn_poisson_range((0.2, 0.35), (0.3, 0.4)) == ((0.3, 0.35), None)
    drawn, note = poisson.drawn_poisson_range((0.2, 0.35), (0.38, 0.45))
    assert drawn == (0.2, 0.35) and "outside the tolerated 0.2-0.35" in note
