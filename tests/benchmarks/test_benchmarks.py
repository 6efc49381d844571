"""The benchmark scripts compute what they claim (quick settings; no timing assertions)."""

import signal
import subprocess
import sys

import pytest

from benchmarks import realtime, serial_cycle, tactile_sensors


@pytest.mark.slow
def test_realtime_rows_are_positive_ratios():
    results = realtime.run(quick=True)
    (row,) = results["rows"]
    assert row["physics_rtf"] > 0 and row["rig_rtf"] > 0 and row["full_run_rtf"] > 0
    assert row["rig_hand_rtf"] > 0 and row["scan_ms"] > 0
    assert "| block (default) | fast | trilinear |" in realtime.to_markdown(results)


def test_serial_cycle_rows_carry_the_wire_limit_beside_the_rate():
    results = serial_cycle.run(quick=True)
    assert len(results["rows"]) == len(serial_cycle.CONFIGS)
    for row in results["rows"]:
        assert row["measured_hz"] > 0
        assert row["limit_hz"] == 38400 / (10 * row["bytes_per_cycle"])
        # physics, not a timing target: no cycle beats the wire (a byte reaches the host once it crossed)
        assert row["measured_hz"] <= row["limit_hz"], row
    assert (
        "| hand interface (LCV+LCPG / LFV+LFS+LFAP, 1234) | pty | 26 | 147.7 |"
        in serial_cycle.to_markdown(results)
    )
    assert "| ratio | lost |" in serial_cycle.to_markdown(results)  # late replies recovered and counted


def test_serial_cycle_stops_an_emulator_that_is_slow_to_leave_without_raising():
    """A process that ignores SIGTERM with its output pipe full (a loaded machine's slow emulator):
    stop() drains, kills and returns, so the benchmark keeps the rows it measured (issue 37)."""
    code = (
        "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('ready', flush=True); "
        "print('x' * 200000, flush=True); time.sleep(120)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "ready\n"  # SIGTERM is ignored from here on
    serial_cycle.stop(proc, timeout_s=1.0)
    assert proc.returncode == -signal.SIGKILL


def test_why_the_pads_bin_contact_forces():
    """The evidence behind twin/sim/tactile.py's choice, kept true by a test (docs/tactile_methods.md)."""
    rows = {r["object"]: r for r in tactile_sensors.run(quick=True)["rows"]}
    for row in rows.values():  # binning conserves the load, rigid or soft
        assert row["binning_n"] == pytest.approx(row["load_n"], rel=0.01)
    assert rows["rigid box"]["touch_grid_n"] == pytest.approx(rows["rigid box"]["load_n"], rel=0.01)
    flex = rows["flexcomp foam"]
    # flex contacts: no cell reads the load (MuJoCo 4.0 reads 0 N; 3.17 gave the load with the wrong sign)
    assert flex["touch_grid_n"] <= 0 and flex["touch_grid_cells"] == 0
    assert flex["tactile_nonzero"] == 0  # the native tactile sensor does not see a flexcomp


@pytest.mark.slow
def test_stereo_benchmarks_report_speed_accuracy_and_calibration():
    from benchmarks import stereo_calibration, stereo_pipeline, stereo_run

    pipeline = stereo_pipeline.run(quick=True)
    (row,) = pipeline["speed"]["rows"]
    assert row["fps"] > 0 and row["points"] > 1000
    block = pipeline["accuracy"]["block"]
    assert block["frames"] == 11 and block["median_mm"] < 1.5 and block["coverage"] > 0.6
    assert "| block | 11 |" in stereo_pipeline.to_markdown(pipeline)
    calibration = stereo_calibration.run(quick=True)
    assert calibration["max"]["hand_translation_mm"] < 5 and calibration["max"]["hand_rotation_deg"] < 1
    assert "| hand translation (mm) |" in stereo_calibration.to_markdown(calibration)
    runs = stereo_run.run(quick=True)
    assert [r["stereo_frames"] for r in runs["rows"]] == [61, 61]
    assert all(r["rig_rtf"] > 0 and r["full_rtf"] > 0 and r["mb_per_min"] > 0 for r in runs["rows"])


def test_the_fidelity_bench_squeezes_a_faithful_block_as_uniaxial_compression_says():
    """Between frictionless plates the block is in uniform uniaxial stress: F = E A strain (analytic), which
    linear tetrahedra represent exactly; the rest is contact softness and MuJoCo's finite-strain model."""
    from benchmarks import foam_fidelity

    foam = foam_fidelity.LIBRARY["block"].with_overrides(fidelity="faithful")
    sim = foam_fidelity.simulate(foam, "plate", modulus_scale=1.0)  # the flex's own elasticity
    analytic = [foam_fidelity.uniaxial_force_n(foam, d / 1e3) for d in foam_fidelity.DEPTHS_MM]
    assert sim["warnings"] == {}
    assert sim["force_n"][0] == pytest.approx(analytic[0], rel=0.10)
    assert sim["force_n"][1] == pytest.approx(analytic[1], rel=0.15)


def test_punch_errors_count_only_what_lies_outside_the_fem_bracket():
    from benchmarks.foam_fidelity import outside_bracket

    assert outside_bracket(10.0, 9.0, 11.0) == 0.0
    assert outside_bracket(12.1, 9.0, 11.0) == pytest.approx(0.1)
    assert outside_bracket(8.1, 9.0, 11.0) == pytest.approx(-0.1)


@pytest.mark.slow
def test_two_opposite_pairs_see_the_poisson_ratio_in_the_grasp():
    """The benchmark's statistic moves with nu: the fast block squeezed at nu 0.2 and 0.35 (same E,
    placement and seed), its width grows and its top sinks, and -eps_x/eps_z rises by over 0.1 (the
    benchmark's simulations: 0.14-0.26 over that range)."""
    from dataclasses import replace

    from benchmarks import nu_from_cameras
    from twin.sim.foam import LIBRARY

    ratios = []
    for nu in (0.2, 0.35):
        seen = nu_from_cameras.observe(replace(LIBRARY["block"], young_pa=45e3, poisson=nu), seed=7)
        eps_x, eps_z = seen.strains()
        assert eps_x > 0 > eps_z
        ratios.append(seen.ratio())
    assert ratios[1] - ratios[0] > 0.1


@pytest.mark.slow
def test_the_bare_replay_is_the_runs_own_physics_step_for_step():
    """run_overhead's denominator: the run's mj_step calls again with its controls and clutch switches
    end exactly where the run ended (MuJoCo is deterministic), step for step; the row carries the
    replay's and the CLI run's times for the ratios (their values are the benchmark's, not asserted)."""
    from benchmarks import run_overhead

    row = run_overhead.measure("block", 1.0)
    assert row["steps"] >= 500 and row["replay_max_qpos_error"] == 0.0  # 1 s of 2 ms steps, and after
    assert row["replay_s"] > 0 and row["cli_s"] > 0
    table = run_overhead.to_markdown({"duration_s": 1.0, "rows": [row], "load": 1.0, "cores": 2})
    assert "| run / replay |" in table.replace("**", "") and "largest joint difference" in table


def test_the_bridge_takes_the_cases_the_sims_draw_numbered(tmp_path):
    """identification_hardware_numbered draws identification_cameras' hidden cases again and finds the
    ones that benchmark's sim runs gave a number for: the same shapes, sizes and moduli in its order."""
    from benchmarks.identification_hardware_numbered import NUMBERED, numbered_cases

    cases = numbered_cases(tmp_path)
    assert [(c["shape"], round(c["young_pa"] / 1e3, 1)) for c in cases] == list(NUMBERED)
    assert [round(1e3 * c["size_m"][2]) for c in cases] == [89, 61, 60]  # the table's heights (mm)


def test_the_fems_two_condensations_give_the_same_forces():
    """benchmarks/fem_condensation.py (quick: the library block's coarsest FEM level) solves one case by
    fem.condense and by the right-hand-side baseline: the same forces; fem.condense and the suite's
    calibration cache are put back."""
    import os

    from benchmarks import fem_condensation
    from twin.sim import fem

    condense, cache = fem.condense, os.environ.get("TWIN_CACHE_DIR")
    results = fem_condensation.run(quick=True)
    assert fem.condense is condense and os.environ.get("TWIN_CACHE_DIR") == cache
    (row,) = results["rows"]
    assert row["candidates"] > 100 and row["dofs"] > 1000
    assert row["max_rel_diff"] < 1e-10 and all(f > 0 for f in row["force_per_pa_n"])
    assert "| library block | 8 |" in fem_condensation.to_markdown(results)
