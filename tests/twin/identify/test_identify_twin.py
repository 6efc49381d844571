"""Eq. 4 identified on twin runs, checked against what the twin knows: its contact forces and the
balance of torques at the distal joint; `twin identify` adds the modulus (tests in test_modulus.py)."""

import json

import numpy as np
import pytest

from tests.twin.identify.conftest import SPHERE_YOUNG_PA
from twin.cli import main
from twin.identify.hand_dynamics import identify_hand
from twin.identify.identify import compression_window, grip_stiffness, identify_run
from twin.identify.signals import MissingStreamError, load_signals
from twin.recording.reader import Run
from twin.viz.rerun_log import read_rrd_scalars


@pytest.fixture(scope="module")
def ident(sphere_run, free_run):
    return identify_run(sphere_run, free_run)


def test_eq4_alone_leaves_the_modulus_to_the_cli(ident):
    """identify_run reads the recording only: eq. 4, the grip and the squeeze stiffness; the modulus is
    twin.sim.modulus's, which runs the procedure in the twin (`twin identify` joins the two)."""
    assert ident.material is None and ident.to_json()["material"] is None


def test_the_grasp_stiffnesses_are_steady_from_cycle_to_cycle(ident):
    """The grip (gauges on drives) and the squeeze stiffness (the fingertips' summed force on their summed
    travel) repeat from cycle to cycle to a few per cent on a held foam; the squeeze is of the order of
    the fingertips' secants summed (it is a slope, they are secants from first contact)."""
    k, sigma = ident.grip
    assert k > 0 and 0 < sigma < 0.05 * k
    s, s_sigma = ident.squeeze
    assert 0 < s_sigma < 0.05 * s
    assert 0.3 < s / sum(f.secant_n_m for f in ident.fingers) < 3


def test_grip_stiffness_is_the_slope_of_summed_torque_on_summed_drive(sphere_run):
    """On the run's own signals with a known law written over the gauges: slope and 1-sigma come back."""
    signals = load_signals(sphere_run)
    window, cycles = compression_window(signals)
    rng = np.random.default_rng(0)
    drive = signals.drive_counts.sum(axis=1)
    law = 0.25 + 0.2e-3 * drive  # 0.2 N*m per 1000 counts
    noise = rng.normal(0, 0.01, len(drive))
    signals.torque_nm = np.column_stack([law + noise, np.zeros_like(law), np.zeros_like(law)])
    k, sigma = grip_stiffness(signals, window, cycles)
    assert k == pytest.approx(0.2, abs=4 * sigma) and sigma < 0.02


def test_eq4_balances_at_the_distal_joint(ident, sphere_run):
    """Strain-gauge torque less the hand's own terms equals the pads' moment about the distal joint."""
    truth = Run(sphere_run).stream("truth")
    for f in ident.fingers:
        tau_ext = f.reaction_torque_n * f.moment_arm_m
        assert f.eq4_residual_rms_nm < 0.15 * np.mean(np.abs(tau_ext)), f.finger
        assert 0.005 < f.moment_arm_m < 0.047  # the pressure centre lies on the fingertip pad
        # the pads' lumped force (eq. 6) against the twin's own contact force on the outer link
        in_window = np.isin(truth.t_s, f.t_s)
        true_force = truth["tip_contact_force_n"][in_window, f.finger - 1]
        assert np.median(np.abs(f.reaction_tactile_n - true_force) / true_force) < 0.15, f.finger


def test_the_reaction_model_follows_the_measured_force(ident):
    for f in ident.fingers:
        assert f.fit.r2 > 0.8 and f.secant_n_m > 0
        assert np.sqrt(np.mean((f.reaction_model_n - f.reaction_tactile_n) ** 2)) == pytest.approx(
            f.fit.rms_n
        )
    thumb = ident.fingers[2]
    assert thumb.cycles >= 4 and thumb.delta_m.mean() > 0.001  # whole cycles, millimetres into the foam


def test_hunt_crossley_fits_the_same_run(sphere_run):
    hc = identify_run(sphere_run, model="hunt-crossley")
    assert all(1.0 <= f.fit.params["n"] <= 3.0 and f.fit.r2 > 0.8 for f in hc.fingers)
    assert "no free-motion run" in hc.notes[0]


def test_free_motion_identifies_the_empty_hand(free_run):
    signals = load_signals(free_run, need_tactile=False)
    hand = identify_hand(signals)
    swing = np.ptp(signals.outer_rad, axis=0)
    assert (swing > 0.3).all()  # the fingers really swung (> 17 degrees of the distal joint)
    for k in range(3):
        assert hand.rms_nm[k] < 0.02  # the model explains the unloaded gauge to ~2 counts (eq. 2)
        predicted = hand.torque_nm(signals)[:, k]
        assert np.sqrt(np.mean((predicted - signals.torque_nm[:, k]) ** 2)) == pytest.approx(hand.rms_nm[k])


def test_a_run_without_pads_is_refused_naming_the_stream(no_tactile_run, capsys):
    with pytest.raises(MissingStreamError, match="no 'tactile' stream, which the reaction force R"):
        identify_run(no_tactile_run)
    assert main(["identify", str(no_tactile_run)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no 'tactile' stream" in err


def test_cli_writes_results_figure_and_rerun_file_with_the_modulus(sphere_identified, free_run):
    """`twin identify --json` prints the results file it wrote: eq. 4 per finger and the modulus the
    twin inferred, which on a sim run is set beside the twin's own (the truth) with its error."""
    code, printed, out = sphere_identified
    assert code == 0
    assert printed == json.loads((out / "identify.json").read_text())
    assert len(printed["fingers"]) == 3 and printed["hand_terms"]["source"] == str(free_run)
    m = printed["material"]
    low, high = m["ci95_pa"]
    assert 0 < low < m["young_pa"] < high and set(m["sigma_log"]) == {"noise", "nuisance", "total"}
    assert m["object"]["shape"] == "sphere" and m["twin_young_pa"] == SPHERE_YOUNG_PA
    assert m["error"] == pytest.approx(m["young_pa"] / SPHERE_YOUNG_PA - 1)
    # no stereo pairs: nu is the tolerated range, drawn, and the results say what two pairs would add
    assert m["poisson"]["poisson_ci95"] == [0.2, 0.35] and "poisson" not in m["poisson"]
    assert "--camera-placement lateral,opposite" in m["poisson"]["cameras_would_add"]
    assert (out / "identify.png").stat().st_size > 10_000
    # the figure's series in Rerun, on the run's timeline (the viewer merges it with run.rrd)
    ident = identify_run(printed["run"], free_run)
    for f in ident.fingers:
        t, r = read_rrd_scalars(out / "identify.rrd", f"plots/identify/f{f.finger}/tactile_n")
        assert np.allclose(t, f.t_s) and np.allclose(r, f.reaction_tactile_n)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["identify", "/nonexistent/run"], "not a run directory"),
        (
            ["identify", "{run}", "--free", "/nonexistent/free"],
            "argument --free: /nonexistent/free: not a run directory",
        ),
    ],
)
def test_bad_identify_input_is_one_line(argv, message, sphere_run, capsys):
    assert main([a.format(run=sphere_run) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_the_figure_is_drawn_even_when_its_worker_process_dies(ident, tmp_path):
    """`twin identify` draws in a spawned worker; where that worker cannot run (a script without a
    __main__ guard) or dies, the caller draws the same figure itself."""
    from twin.identify.report import FigureProcess, figure_series

    path = tmp_path / "identify.png"
    with FigureProcess() as worker:
        worker._process.kill()
        worker._process.join(5)
        worker.draw(figure_series(ident), path)
        worker.wait()
    assert path.stat().st_size > 10_000 and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_rerun_file_names_and_colours_its_series_on_its_own(ident, tmp_path):
    """identify.rrd opened alone (without the run's blueprint) still says what each series is: a static
    name per finger and route, in the finger's colour."""
    import rerun as rr
    from rerun.chunk import RrdReader

    from twin.identify.report import log_rerun

    path = log_rerun(ident, tmp_path / "identify.rrd")
    component = rr.SeriesLines.descriptor_names().component
    names = {
        chunk.entity_path: chunk.to_record_batch().column(component).to_pylist()[0]
        for chunk in RrdReader(path).stream().filter(is_static=True)
        if component in chunk.to_record_batch().schema.names
    }
    assert names["/plots/identify/f1/tactile_n"] == ["F1 R tactile (eq. 6)"]
    assert names["/plots/identify/f3/indentation_mm"] == ["F3 indentation (mm)"]
    assert len(names) == 4 * len(ident.fingers)


def test_writing_the_rerun_file_inside_the_run_warns_of_nothing(ident, sphere_run, tmp_path):
    """`twin identify RUN` writes RUN/identify/identify.rrd while it reads the run's recordings for the
    blueprint: it must not read its own file half-written (Rerun warned "RRD file has no footer" on every
    identify of the README's quick start)."""
    import dataclasses
    import shutil
    import warnings

    from twin.identify.report import log_rerun

    run = tmp_path / "run"
    shutil.copytree(sphere_run, run, ignore=shutil.ignore_patterns("identify", "fit"))
    (run / "identify").mkdir()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log_rerun(dataclasses.replace(ident, run_path=run), run / "identify" / "identify.rrd")
    assert not [str(w.message) for w in caught if "rerun" in w.category.__module__.lower()]


def test_the_rerun_file_carries_the_result_and_a_blueprint_that_shows_it(sphere_identified):
    """`rerun run.rrd identify/identify.rrd`, without `twin view`: identify.rrd holds the result as a
    Markdown document (E, its interval, k_s and R^2 per finger) and the run's blueprint with an
    identification tab whose first view shows that document."""
    from rerun.chunk import RrdReader

    from twin.viz.rerun_log import read_rrd_blueprint, read_rrd_scalars

    code, printed, out = sphere_identified
    assert code == 0
    rrd = out / "identify.rrd"
    documents = [
        chunk.to_record_batch().column("TextDocument:text").to_pylist()[0]
        for chunk in RrdReader(rrd).stream().filter(is_static=True)
        if chunk.entity_path == "/identify/result"
    ]
    assert len(documents) == 1
    m = printed["material"]
    low, high = (v / 1e3 for v in m["ci95_pa"])
    assert f"E = {m['young_pa'] / 1e3:.1f} kPa" in documents[0][0]
    assert f"{low:.1f}-{high:.1f} kPa" in documents[0][0]
    for f in printed["fingers"]:
        assert f"| F{f['finger']} | {f['secant_stiffness_n_m']:.0f} |" in documents[0][0]
    views = {
        columns.get("ViewBlueprint:class_identifier", [None])[0]: columns.get("ViewBlueprint:space_origin")
        for columns in read_rrd_blueprint(rrd).values()
        if "ViewBlueprint:class_identifier" in columns
    }
    assert views["TextDocument"] == ["/identify/result"]
    assert "3D" in views and "TimeSeries" in views  # the run's own views beside it
    # the identification's own views ranged over the series identify.rrd holds (opened without twin view)
    blueprint = read_rrd_blueprint(rrd)
    ranged = 0
    for path, columns in blueprint.items():
        if columns.get("ViewBlueprint:space_origin") != ["/plots/identify"]:
            continue
        axis = {k: v for p, c in blueprint.items() if p.startswith(f"{path}/") for k, v in c.items()}
        assert "ScalarAxis:range" in axis, columns.get("ViewBlueprint:display_name")
        low, high = axis["ScalarAxis:range"][0]
        contents = {
            c for p, cs in blueprint.items() if p.startswith(path) for c in cs.get("ViewContents:query", [])
        }
        for entity in contents:
            _, values = read_rrd_scalars(rrd, entity)
            assert low <= np.nanmin(values) and np.nanmax(values) <= high, (entity, low, high)
        ranged += 1
    assert ranged == 4  # three fingers' reaction forces and the indentations
