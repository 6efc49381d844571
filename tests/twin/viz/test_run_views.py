"""Every kind of run's own recording, read back with Rerun's reader: each view of its blueprint shows
something the run recorded, every time-series view has a y range that holds the run's values, and the
events (phases, the force cap, a clipped or refused command, a recovered hardware cycle, a hardware
loop behind its schedule) are lanes and log rows at the instants they happened."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader
from twin.experiments.compress import PHASES, CompressController
from twin.hardware.backend import HardwareBackend
from twin.hardware.bh262.emulator import make_hand_emulator
from twin.hardware.rig_config import RigConfig

from twin.cli import main
from twin.interface.devices import HandCommand, HandReading
from twin.recording import open_run
from twin.safety import UnsafeCommandError
from twin.session import run_experiment
from twin.sim.backend import SimBackend
from twin.sim.foam import LIBRARY
from twin.viz.blueprint import COMPRESS_PHASE, kind_of_run
from twin.viz.rerun_log import read_rrd_blueprint, read_rrd_entities, read_rrd_scalars

STATE = rr.StateChange.descriptor_state().component
TEXT = rr.TextLog.descriptor_text().component
LEVEL = rr.TextLog.descriptor_level().component


def _twin_run(tmp_path_factory, name: str, *argv: str) -> Path:
    out = tmp_path_factory.mktemp(name) / "run"
    assert main(["run", *argv, "--out", str(out), "--no-progress"]) == 0
    return out


@pytest.fixture(scope="module")
def compress_run(tmp_path_factory) -> Path:
    """Into the compress phase (it starts at ~2.6 s)."""
    return _twin_run(tmp_path_factory, "compress", "compress", "--duration", "5")


@pytest.fixture(scope="module")
def free_run(tmp_path_factory) -> Path:
    return _twin_run(tmp_path_factory, "free", "free", "--duration", "1.5")


@pytest.fixture(scope="module")
def camera_run(tmp_path_factory) -> Path:
    return _twin_run(tmp_path_factory, "cameras", "compress", "--cameras", "--duration", "1")


class LateOnce(CompressController):
    """The compress procedure, 120 ms late on readings 15-17: the 30 Hz loop falls behind, then
    catches up."""

    def __init__(self) -> None:
        super().__init__()
        self.readings = 0

    def __call__(self, reading: HandReading) -> HandCommand | None:
        self.readings += 1
        if 15 <= self.readings <= 17:
            time.sleep(0.12)
        return super().__call__(reading)


@pytest.fixture(scope="module")
def hardware_run(tmp_path_factory) -> Path:
    """A hand-only hardware run against the in-process emulator: one garbled reply (a recovered cycle)
    and a loop that falls behind its schedule for a few readings."""
    out = tmp_path_factory.mktemp("hardware") / "run"
    with make_hand_emulator("block", faults="garbage@40") as emulator:
        backend = HardwareBackend(RigConfig().with_hand_port(emulator.serve_tcp()))
        run_experiment(
            backend=backend,
            controller=LateOnce(),
            phases=PHASES,
            duration_s=2.0,
            run_dir=out,
            experiment={"name": "compress"},
        )
    return out


@pytest.fixture(scope="module")
def hardware_pads_run(tmp_path_factory) -> Path:
    """A hardware run with the hand and the pads against their in-process emulators; the pads' emulator
    never sends its 20th frame (a sequence gap: one frame lost)."""
    from twin.hardware.pps.emulator import make_tactile_emulator
    from twin.hardware.rig_config import TactilePortConfig

    out = tmp_path_factory.mktemp("hardware-pads") / "run"
    table = SimBackend(LIBRARY["block"]).write_calibration(out.parent / "calibration")["tactile_table"]
    with make_hand_emulator("block") as hand, make_tactile_emulator("ramp", faults="drop@20") as pads:
        port = TactilePortConfig(url=pads.serve_tcp(0))
        config = RigConfig(tactile_port=port, calibration={"tactile_table": table})
        run_experiment(
            backend=HardwareBackend(config.with_hand_port(hand.serve_tcp())),
            controller=CompressController(),
            phases=PHASES,
            duration_s=1.5,
            run_dir=out,
            experiment={"name": "compress"},
        )
    return out


def _views(rrd: Path) -> dict[str, dict[str, object]]:
    """View id -> its blueprint columns (class, origin, contents, y range, time ranges), from the last
    blueprint in the file (Rerun's reader)."""
    blueprint = read_rrd_blueprint(rrd)
    views = {p: dict(c) for p, c in blueprint.items() if "ViewBlueprint:class_identifier" in c}
    for path, columns in blueprint.items():
        for view in views:
            if path.startswith(f"{view}/") and path.count("/") == view.count("/") + 1:
                views[view].update(columns)
    return views


def _shows(view: dict[str, object], entities: dict[str, int]) -> bool:
    """Whether a view's query (its origin's subtree, or the entities it names) matches a logged entity."""
    origin = str(view.get("ViewBlueprint:space_origin", ["/"])[0])
    query = view.get("ViewContents:query") or ["$origin/**"]
    for rule in query:
        rule = rule.replace("$origin", origin.rstrip("/"))
        if rule.endswith("/**"):
            root = rule.removesuffix("/**")
            if any(e == root or e.startswith(root + "/") for e in entities):
                return True
        elif rule in entities:
            return True
    return False


def _check_every_view(rrd: Path) -> set[str]:
    """No view empty; each time series has data at every entity it names and a y range holding it
    (the compression window: the data from its own start on). The views' names."""
    entities = read_rrd_entities(rrd)
    views = _views(rrd)
    assert views
    for view in views.values():
        name = view["ViewBlueprint:display_name"][0]
        assert _shows(view, entities), f"view {name!r} shows nothing the run recorded"
        if view["ViewBlueprint:class_identifier"][0] != "TimeSeries":
            continue
        assert "ScalarAxis:range" in view, f"time-series view {name!r} has no y range"
        low, high = view["ScalarAxis:range"][0]
        assert low < high, name
        start = -np.inf
        ranges = view.get("VisibleTimeRanges:ranges")
        if ranges:  # the compression window: from the compress phase on
            (window,) = [r for r in ranges if r["timeline"] == "sim_time"]
            start = window["range"]["start"] / 1e9
        for entity in view["ViewContents:query"]:
            t, values = read_rrd_scalars(rrd, entity)  # KeyError: a named series with no data
            shown = values[t >= start - 1e-9]
            assert low <= np.nanmin(shown) and np.nanmax(shown) <= high, (name, entity, low, high)
    return {v["ViewBlueprint:display_name"][0] for v in views.values()}


def _states(rrd: Path, lane: str) -> list[tuple[float, str | None]]:
    """(time s, state or None where cleared) of an events lane, in time order."""
    out = []
    for chunk in RrdReader(rrd).stream().filter(content=f"/events/{lane}"):
        batch = chunk.to_record_batch()
        if STATE not in batch.schema.names:
            continue
        t = batch.column("sim_time").to_numpy(zero_copy_only=False).astype("timedelta64[ns]").astype(np.int64)
        for ti, v in zip(t / 1e9, batch.column(STATE).to_pylist(), strict=True):
            out.append((float(ti), v[0] if v else None))
    return sorted(out, key=lambda r: r[0])


def _log(rrd: Path) -> list[tuple[str, str]]:
    """(level, text) of every text-log row."""
    rows = []
    for chunk in RrdReader(rrd).stream().filter(content="/log", components=[TEXT, LEVEL]):
        batch = chunk.to_record_batch()
        levels = batch.column(LEVEL).to_pylist() if LEVEL in batch.schema.names else [None] * batch.num_rows
        for text, level in zip(batch.column(TEXT).to_pylist(), levels, strict=True):
            if text:
                rows.append((level[0] if level else "INFO", text[0]))
    return rows


def test_a_sim_compress_run_has_every_view_filled_and_ranged(compress_run):
    names = _check_every_view(compress_run / "run.rrd")
    start = next(t for t, s in _states(compress_run / "run.rrd", "phase") if s == COMPRESS_PHASE)
    assert f"compression window, from the compress phase at {start:.1f} s (counts)" in names
    assert "tip contact force: eq. 6 - true (N): F1 red, F2 blue, F3 green" in names


def test_twin_view_gives_a_run_the_ranges_its_recording_closed_with(compress_run, tmp_path):
    """`twin view` builds the blueprint from the run's files (a killed run's recording has none): the
    same views with the same y ranges and compression window as the recording's own."""
    from twin.cli.view import view_files

    rbl = tmp_path / "view.rbl"
    view_files(compress_run, rbl)

    def ranged(path: Path) -> dict[str, object]:
        return {
            v["ViewBlueprint:display_name"][0]: (v.get("ScalarAxis:range"), v.get("VisibleTimeRanges:ranges"))
            for v in _views(path).values()
            if v["ViewBlueprint:class_identifier"][0] == "TimeSeries"
        }

    own, built = ranged(compress_run / "run.rrd"), ranged(rbl)
    assert own.keys() == built.keys()
    for name, (y, window) in own.items():
        np.testing.assert_allclose(built[name][0], y, rtol=1e-12, err_msg=name)
        assert built[name][1] == window, name


def test_a_free_run_has_every_view_filled_and_ranged(free_run):
    names = _check_every_view(free_run / "run.rrd")
    assert not any(n.startswith("compression window") for n in names)


@pytest.mark.slow
def test_a_camera_run_has_every_view_filled_and_ranged(camera_run):
    names = _check_every_view(camera_run / "run.rrd")
    assert {"left camera", "reconstruction error vs truth (mm): median dark, p90 light"} <= names


@pytest.mark.slow
def test_a_hardware_run_has_every_view_filled_and_ranged_and_marks_its_cycles(hardware_run):
    """The hand-only hardware run: no pad or truth views, the rest filled and ranged; the recovered
    cycle is a lane and a warning at the reading that followed it, the late loop a lane from the first
    reading over a period behind its schedule until one back within it."""
    rrd = hardware_run / "run.rrd"
    names = _check_every_view(rrd)
    assert not any(n.startswith(("tactile", "pad forces", "tip contact force")) for n in names)
    run = open_run(hardware_run)
    assert len(run.metadata["hand_recoveries"]) == 1
    t_hand = run.stream("hand").t_s
    (recovered, cleared) = _states(rrd, "hand_cycle")
    assert recovered[1] == "recovered" and cleared[1] is None
    k = int(np.argmin(np.abs(t_hand - recovered[0])))  # the .rrd keeps whole nanoseconds
    assert t_hand[k] == pytest.approx(recovered[0], abs=1e-6) and t_hand[k + 1] == pytest.approx(
        cleared[0], abs=1e-6
    )
    assert any(level == "WARN" and text.startswith("hand cycle recovered (1): ") for level, text in _log(rrd))
    loop = _states(rrd, "hand_loop")
    assert loop[0][1] == "behind its 30 Hz schedule" and loop[-1][1] is None
    period = 1 / 30
    late = t_hand - np.arange(len(t_hand)) * period  # each reading's delay after its slot
    first = int(np.argmax(late > period))
    assert loop[0][0] == pytest.approx(t_hand[first], abs=1e-6)
    assert late[int(np.argmin(np.abs(t_hand - loop[-1][0])))] <= period  # back on schedule where it ends


@pytest.mark.slow
def test_a_hardware_run_with_pads_has_every_view_filled_and_marks_a_lost_frame(hardware_pads_run):
    """The pads' views are there and filled; the lost frame is a lane and a warning at the scan after
    it, where the recorded count of dropped frames steps, cleared at the next scan."""
    rrd = hardware_pads_run / "run.rrd"
    names = _check_every_view(rrd)
    assert "pad forces, eq. 6 (N)" in names and any(n.startswith("tactile pressure") for n in names)
    tactile = open_run(hardware_pads_run).stream("tactile")
    dropped = np.asarray(tactile["dropped_frames"])
    (step,) = np.flatnonzero(np.diff(dropped)) + 1
    (lost, cleared) = _states(rrd, "tactile_frames")
    assert lost[1] == "frames lost" and cleared[1] is None
    assert lost[0] == pytest.approx(tactile.t_s[step], abs=1e-6)
    assert cleared[0] == pytest.approx(tactile.t_s[step + 1], abs=1e-6)
    rows = [t for level, t in _log(rrd) if level == "WARN" and t.startswith("tactile: ")]
    assert rows == [f"tactile: 1 frame(s) lost before this scan, {dropped[step]} so far"]


def test_a_clipped_command_is_a_lane_where_the_finger_sits_at_the_cap(tmp_path):
    """The safety layer holds a finger at the force cap: its command lane says 'clipped' only at
    commands answering a reading that had it at the cap, and the log says what was asked and what was
    sent. The compress procedure keeps its squeeze under the 2 kg cap (issue 38), so this run's rig
    declares a 1 kg cap, which the grasp reaches."""
    from twin.safety import SafetyLayer, SafetyLimits

    cap_kg = 1.0
    out = tmp_path / "run"
    run_experiment(
        backend=SimBackend(LIBRARY["block"]),
        controller=CompressController(),
        phases=PHASES,
        duration_s=4.0,
        run_dir=out,
        experiment={"name": "compress"},
        safety=SafetyLayer(SafetyLimits(max_fingertip_force_kg=cap_kg)),
    )
    rrd = out / "run.rrd"
    run = open_run(out)
    hand, command = run.stream("hand"), run.stream("command")
    lanes = {k: [t for t, s in _states(rrd, f"F{k + 1}_command") if s == "clipped"] for k in range(3)}
    assert any(lanes.values()), "no command held at a 1 kg cap in a grasp of the block"
    for k, clipped in lanes.items():
        for t in clipped:
            i = int(np.searchsorted(hand.t_s, t, side="right")) - 1  # the reading this command answers
            assert hand["force_kg"][i][k] >= cap_kg
            assert np.isclose(command.t_s, t, atol=1e-6).any()
        rows = [text for _, text in _log(rrd) if text.startswith(f"F{k + 1} command clipped: ")]
        assert len(rows) == len(clipped)
        assert all("held by the safety layer at the 1 kg force cap" in r for r in rows)
    # The run's own cap, not the datasheet's 2 kg: the line, the events, the force view (title, y range)
    _, cap_line = read_rrd_scalars(rrd, "/plots/hand/force_cap_kg")
    assert np.all(cap_line == cap_kg)
    assert any(s == "at the 1 kg cap" for k in range(3) for _, s in _states(rrd, f"F{k + 1}_force_cap"))
    (force,) = [v for v in _views(rrd).values() if "eq. 3" in v["ViewBlueprint:display_name"][0]]
    assert "the 1 kg cap" in force["ViewBlueprint:display_name"][0]
    assert force["ScalarAxis:range"][0][1] < 2.0  # the datasheet's cap would need 2.5 kg
    assert kind_of_run(out).force_cap_kg == cap_kg  # `twin view` rebuilds it from run.json


def test_the_difference_plots_are_the_estimate_minus_the_truth(compress_run):
    rrd = compress_run / "run.rrd"
    for diff, estimate, truth in (
        ("tip_force_n", "/plots/tactile/tip_force_n", "/plots/truth/tip_contact_force_n"),
        ("outer_rad", "/plots/observer/outer_rad", "/plots/truth/outer_rad"),
    ):
        t_d, d = read_rrd_scalars(rrd, f"/plots/difference/{diff}")
        t_e, e = read_rrd_scalars(rrd, estimate)
        t_t, r = read_rrd_scalars(rrd, truth)
        assert len(t_d) >= 0.9 * len(t_e)  # the pads and the hand are sampled at the same instants
        i, j = np.searchsorted(t_e, t_d), np.searchsorted(t_t, t_d)
        np.testing.assert_allclose(t_e[i], t_d, atol=1e-9)
        np.testing.assert_allclose(t_t[j], t_d, atol=1e-9)
        np.testing.assert_allclose(d, e[i] - r[j], atol=1e-9)


class Refusing(CompressController):
    """The compress procedure until its 10th reading, then a set point past the drive's range."""

    def __init__(self) -> None:
        super().__init__()
        self.readings = 0

    def __call__(self, reading: HandReading) -> HandCommand | None:
        self.readings += 1
        if self.readings == 10:
            return HandCommand(np.array([30_000.0, 0.0, 0.0, 0.0]), 5000)
        return super().__call__(reading)


def test_a_refused_command_is_a_lane_and_an_error_row_where_the_run_stopped(tmp_path):
    with pytest.raises(UnsafeCommandError):
        run_experiment(
            backend=SimBackend(LIBRARY["block"], seed=0),
            controller=Refusing(),
            phases=PHASES,
            duration_s=2.0,
            run_dir=tmp_path / "run",
            experiment={"name": "compress"},
        )
    rrd = tmp_path / "run" / "run.rrd"
    ((t, state),) = _states(rrd, "run")
    t_hand = open_run(tmp_path / "run").stream("hand").t_s
    assert state == "command refused" and t_hand[9] <= t < t_hand[9] + 1 / 30  # at the 10th reading
    errors = [text for level, text in _log(rrd) if level == "ERROR"]
    assert len(errors) == 1 and "30000" in errors[0] and "the hand was idled" in errors[0]


def test_the_tactile_colour_bar_spans_the_pads_scale_and_the_labels_stand_apart(compress_run):
    """The colour bar is the pads' colour map over the pads' own range (read back in kPa: the scale's top
    at the top, 0 at the bottom), ticked with it; the canvas's labels are short and 20 mm or more apart
    (the 18 mm pads sit 30 mm apart: six full names ran into each other)."""
    from twin.viz.rerun_log import read_rrd_images

    rrd = compress_run / "run.rrd"
    scale = float(
        [t for _, t in _log(rrd) if t.startswith("tactile colour scale: 0-")][-1].split("-")[1].split()[0]
    )
    depth_range = rr.DepthImage.descriptor_depth_range().component
    ranges = {
        chunk.entity_path: chunk.to_record_batch().column(depth_range).to_pylist()[-1]
        for chunk in RrdReader(rrd).stream().filter(is_static=True, components=[depth_range])
        if depth_range in chunk.to_record_batch().schema.names
    }
    assert (
        len({tuple(np.ravel(r)) for r in ranges.values()}) == 1 and "/tactile/colour_bar" in ranges
    )  # one range
    bar = read_rrd_images(rrd, "/tactile/colour_bar")[-1][1]  # static, logged again as the scale rose
    assert (
        bar[0, 0] == pytest.approx(scale, abs=0.1) and bar[-1, 0] == 0.0 and (np.diff(bar[:, 0]) <= 0).all()
    )
    labels = rr.Points2D.descriptor_labels().component
    positions = rr.Points2D.descriptor_positions().component
    (ticks,) = [
        chunk.to_record_batch().column(labels).to_pylist()[-1]
        for chunk in RrdReader(rrd).stream().filter(content="/tactile/scale", is_static=True)
    ]
    assert ticks[-1] == f"{scale:g} kPa" and ticks[0] == "0"
    (names,) = [
        (
            chunk.to_record_batch().column(labels).to_pylist()[-1],
            chunk.to_record_batch().column(positions).to_pylist()[-1],
        )
        for chunk in RrdReader(rrd).stream().filter(content="/tactile/names", is_static=True)
    ]
    text, where = names
    assert set(text) == {"F1", "F2", "F3", "tip", "inner", "palm"}
    xy = np.array(where)
    gaps = np.linalg.norm(xy[:, None] - xy[None], axis=2) + np.eye(len(xy)) * 1e9
    assert gaps.min() >= 20.0
