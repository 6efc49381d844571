"""The run blueprints, read back from real .rrd files with Rerun's own reader: views, what they show,
the 3-D eye, fixed finger colours; and a real sim run whose every plotted stream is in some view."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rerun as rr

from twin.cli import main
from twin.viz.blueprint import (
    DEPTH_ENTITY,
    EVENTS_VIEW,
    FINGER_RGB,
    FUSED_CLOUD_ENTITY,
    MESH_ENTITY,
    RunKind,
    lighter,
    run_blueprint,
)
from twin.viz.rerun_log import (
    read_rrd_blueprint,
    read_rrd_entities,
    read_rrd_views,
)

KINDS = {
    "compress": RunKind("compress"),
    "free": RunKind("free"),
    "cameras": RunKind("compress", stereo=True),
    "predict": RunKind("compress", predict=True),
    "identify": RunKind("compress", identify=True),
    "hardware": RunKind("compress", sim=False),
    "hand only": RunKind("compress", sim=False, tactile=False),
}
FINGER_U32 = {f: int.from_bytes(bytes([*rgb, 255]), "big") for f, rgb in FINGER_RGB.items()}
"""Rerun's packed RGBA of each finger's colour."""


def _saved(tmp_path, kind: RunKind):
    path = tmp_path / f"{kind.name}.rrd"
    rec = rr.RecordingStream("barrett_twin_test")
    rec.save(path, default_blueprint=run_blueprint(kind))
    rec.flush()
    rec.disconnect()
    return path


def _overrides(blueprint: dict, entity: str) -> list[dict]:
    """The SeriesLines overrides that the blueprint's views give a plotted entity."""
    marker = f"/ViewContents/overrides{entity}/visualizers/"
    return [cols for path, cols in blueprint.items() if marker in path and "SeriesLines:colors" in cols]


@pytest.mark.parametrize("name", sorted(KINDS))
def test_each_kind_of_run_has_its_views(tmp_path, name):
    kind = KINDS[name]
    path = _saved(tmp_path, kind)
    views = read_rrd_views(path)
    scene = (
        "hand (m, z up)" if kind.experiment == "free" else "hand and foam (m, z up)"
    )  # no foam in a free run
    scenes = [v for t, v in views.items() if t.startswith(scene)]
    assert len(scenes) == 1 and scenes[0]["kind"] == "3D" and scenes[0]["origin"] == "/world"
    coloured_by_error = "stereo points by error to the truth: pale violet 0 to purple >= 5 mm"
    assert (coloured_by_error in next(t for t in views if t.startswith(scene))) == (kind.stereo and kind.sim)
    position = views["finger position (counts), command light: F1 red, F2 blue, F3 green"]
    assert position["contents"] == ["/plots/hand/position_counts", "/plots/command/position_counts"]
    for title in (
        "joint velocity (rad/s)",
        "strain-gauge torque, eq. 2 (N·m)",
        "fingertip force, eq. 3 (kg); grey: the 2 kg cap",
    ):
        assert views[title]["kind"] == "TimeSeries"
    assert "/plots/hand/force_cap_kg" in views["fingertip force, eq. 3 (kg); grey: the 2 kg cap"]["contents"]
    assert views[EVENTS_VIEW] == {
        "kind": "StateTimeline",
        "origin": "/events",
        "contents": ["$origin/**"],
    }
    assert views["log: phases and warnings"] == {
        "kind": "TextLog",
        "origin": "/log",
        "contents": ["$origin/**"],
    }
    tactile = [v for t, v in views.items() if t.startswith("tactile pressure (kPa")]
    assert len(tactile) == kind.tactile and all(v["origin"] == "/tactile" for v in tactile)
    assert ("pad forces, eq. 6 (N)" in views) == kind.tactile  # a hand-only run: no empty pad views
    assert ("compression window, last 4 s (counts)" in views) == (kind.experiment == "compress")
    truth = "tip contact force: true (light) vs eq. 6 (N)"
    assert (truth in views) == kind.sim
    if kind.sim:
        assert views[truth]["contents"] == ["/plots/tactile/tip_force_n", "/plots/truth/tip_contact_force_n"]
        assert (
            "/plots/observer/outer_rad"
            in views["outer joint: true (light) vs clutch observer (rad)"]["contents"]
        )
    cameras = ("left camera", "right camera", "rectified left: depth (m) and contours")
    assert all((c in views) == kind.stereo for c in cameras)
    if kind.stereo:
        assert views["left camera"]["origin"] == "/world/hand/stereo/left"
    assert ("contour: predicted (px)" in views) == (kind.predict and not kind.stereo)
    force = "reaction force R (N): tactile eq. 6 (dark), gauge eq. 4 (mid), model (light)"
    indentation = "indentation δ (mm): F1 red, F2 blue, F3 green"
    identify = [f"F{k} {force}" for k in (1, 2, 3)] + [indentation]
    assert all((v in views) == kind.identify for v in identify)
    if kind.identify:
        assert views[f"F2 {force}"]["contents"] == [
            "/plots/identify/f2/tactile_n",
            "/plots/identify/f2/gauge_eq4_n",
            "/plots/identify/f2/model_n",
        ]
        assert views[indentation]["contents"][0] == "/plots/identify/f1/indentation_mm"


def test_plots_share_one_time_axis_and_the_devices_plots_span_the_devices_range(tmp_path):
    """Stacked plots are linked in time (the same instant at the same x), except the compression window,
    which follows the cursor; position spans the drive's 0-17,800 counts and force 0 to past the cap."""
    blueprint = read_rrd_blueprint(_saved(tmp_path, KINDS["compress"]))

    def by_name(column: str, suffix: str) -> dict[str, object]:
        names = {
            p: c["ViewBlueprint:display_name"][0]
            for p, c in blueprint.items()
            if "ViewBlueprint:display_name" in c
        }
        return {
            names[p.removesuffix(suffix)]: c[column][0]
            for p, c in blueprint.items()
            if column in c and p.removesuffix(suffix) in names
        }

    kinds = by_name("ViewBlueprint:class_identifier", "")
    linked = {n for n, link in by_name("TimeAxis:link", "/TimeAxis").items() if link == 2}
    plots = {n for n, kind in kinds.items() if kind == "TimeSeries"}
    assert plots - linked == {"compression window, last 4 s (counts)"}
    assert EVENTS_VIEW in linked  # the events' lanes too
    ranges = by_name("ScalarAxis:range", "/ScalarAxis")
    assert ranges["finger position (counts), command light: F1 red, F2 blue, F3 green"] == [0.0, 17800.0]
    assert ranges["fingertip force, eq. 3 (kg); grey: the 2 kg cap"] == [0.0, 2.5]


def test_the_3d_eye_looks_at_the_foam_with_z_up(tmp_path):
    target = (0.01, -0.02, 0.35)
    blueprint = read_rrd_blueprint(_saved(tmp_path, RunKind(eye_target_m=target)))
    (eye,) = [cols for path, cols in blueprint.items() if path.endswith("/EyeControls3D")]
    np.testing.assert_allclose(eye["EyeControls3D:look_target"][0], target, atol=1e-6)
    np.testing.assert_allclose(eye["EyeControls3D:eye_up"][0], [0, 0, 1])
    distance = np.linalg.norm(np.subtract(eye["EyeControls3D:position"][0], target))
    assert 0.2 < distance < 0.6  # the hand (~0.2 m) fills the view, not the 25 cm mount column


def test_camera_runs_hide_all_but_one_cloud_and_one_mesh(tmp_path):
    blueprint = read_rrd_blueprint(_saved(tmp_path, KINDS["cameras"]))
    hidden = {
        path.split("/ViewContents/overrides", 1)[1].removesuffix("/visualizers")
        for path, cols in blueprint.items()
        if cols.get("EntityBehavior:visible") == [False]
    }
    assert hidden == {f"/{MESH_ENTITY}", f"/{FUSED_CLOUD_ENTITY}", f"/{DEPTH_ENTITY}"}


def test_finger_colours_are_fixed_in_every_plot(tmp_path):
    blueprint = read_rrd_blueprint(_saved(tmp_path, KINDS["identify"]))
    fingers = [FINGER_U32[f] for f in ("F1", "F2", "F3")]
    measured = _overrides(blueprint, "/plots/hand/position_counts")  # whole run, compression window
    assert len(measured) == 2
    assert all(m["SeriesLines:colors"] == fingers for m in measured)
    assert all(m["SeriesLines:names"] == ["F1", "F2", "F3"] for m in measured)
    light = [int.from_bytes(bytes([*lighter(FINGER_RGB[f]), 255]), "big") for f in ("F1", "F2", "F3")]
    command = _overrides(blueprint, "/plots/command/position_counts")
    assert [c["SeriesLines:colors"] for c in command] == [light, light]
    for entity in ("/plots/hand/torque_nm", "/plots/observer/outer_rad", "/plots/tactile/tip_force_n"):
        assert [o["SeriesLines:colors"] for o in _overrides(blueprint, entity)] == [fingers]
    for k in (1, 2, 3):  # the identification's series get names (report.py logs none) and their colour
        (tactile,) = _overrides(blueprint, f"/plots/identify/f{k}/tactile_n")
        assert tactile["SeriesLines:colors"] == [FINGER_U32[f"F{k}"]]
        assert tactile["SeriesLines:names"] == [f"F{k} R tactile (eq. 6)"]


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "compress"
    assert main(["run", "compress", "--duration", "1.5", "--out", str(out), "--no-progress"]) == 0
    return out


def test_every_stream_of_a_sim_run_is_in_a_view(sim_run):
    path = sim_run / "run.rrd"
    entities = read_rrd_entities(path)
    views = read_rrd_views(path)
    shown = {p for v in views.values() for p in v["contents"]}
    plotted = {e for e in entities if e.startswith("/plots/")}
    assert plotted <= shown, plotted - shown
    assert "other series" not in views  # every series has its place in the compress blueprint
    # Each recorded stream (run.json) shows in the viewer: hand, command, truth, tactile.
    streams = json.loads((sim_run / "run.json").read_text())["streams"]
    for stream in streams:
        assert any(p.startswith(f"/plots/{stream}/") for p in plotted), stream
    assert {"/plots/observer/inner_rad", "/plots/observer/outer_rad"} <= plotted
    for pad in ("palm", "f1_tip", "f3_inner"):
        assert f"/tactile/{pad}" in entities


def test_a_sim_run_logs_its_phases_and_colours_its_fingers(sim_run):
    from rerun.chunk import RrdReader

    path = sim_run / "run.rrd"
    text = rr.TextLog.descriptor_text().component
    lines = [
        line
        for chunk in RrdReader(path).stream().filter(content="/log", components=[text])
        for line in chunk.to_record_batch().column(text).to_pylist()
        if line is not None
    ]
    assert [line[0] for line in lines if line[0].startswith("phase:")][:1] == ["phase: close"]
    assert any(line[0].startswith("tactile colour scale: 0-") for line in lines)
    state = rr.StateChange.descriptor_state().component  # the phases as a lane on the time axis too
    phases = [
        v
        for chunk in RrdReader(path).stream().filter(content="/events/phase")
        for v in chunk.to_record_batch().column(state).to_pylist()
    ]
    assert phases[:1] == [["close"]]
    # the series' colours are in the recording too (static), whichever blueprint the viewer uses
    colors = rr.SeriesLines.descriptor_colors().component
    (row,) = [
        v
        for chunk in RrdReader(path).stream().filter(content="/plots/hand/torque_nm", is_static=True)
        for v in chunk.to_record_batch().column(colors).to_pylist()
    ]
    assert row == [FINGER_U32[f] for f in ("F1", "F2", "F3")]
    # the hand model's finger links in the same colours
    for finger, body in (("F1", "f1_inner"), ("F3", "f3_outer")):
        found = []
        for chunk in RrdReader(path).stream().filter(is_static=True):
            if chunk.entity_path.startswith(f"/world/bodies/{body}/"):
                batch = chunk.to_record_batch()
                found += [
                    v[0] if isinstance(v, list) else v
                    for c in batch.schema.names
                    if c.endswith((":colors", ":albedo_factor"))
                    for v in batch.column(c).to_pylist()
                    if v is not None
                ]
        assert found and set(found) == {FINGER_U32[finger]}, (body, found)


def test_twin_view_writes_the_blueprint_of_the_run_and_says_how_to_serve_it(sim_run, tmp_path):
    from twin.cli.view import GRPC_PORT, WEB_VIEWER_PORT, view_files, web_instructions

    rbl = tmp_path / "view.rbl"
    files = view_files(sim_run, rbl)
    assert files == [str(sim_run / "run.rrd"), str(rbl)]
    views = read_rrd_views(rbl)
    assert "tip contact force: true (light) vs eq. 6 (N)" in views and "left camera" not in views
    (eye,) = [c for p, c in read_rrd_blueprint(rbl).items() if p.endswith("/EyeControls3D")]
    (run_eye,) = [
        c for p, c in read_rrd_blueprint(sim_run / "run.rrd").items() if p.endswith("/EyeControls3D")
    ]
    assert eye["EyeControls3D:look_target"] == run_eye["EyeControls3D:look_target"]  # framed on the foam
    lines = web_instructions(files)
    serve = next(line for line in lines if "--serve-web" in line)
    assert f"--web-viewer-port {WEB_VIEWER_PORT} --port {GRPC_PORT}" in serve and str(rbl) in serve
    ssh = next(line for line in lines if "ssh" in line)
    assert (
        f"-L {WEB_VIEWER_PORT}:localhost:{WEB_VIEWER_PORT}" in ssh
        and f"-L {GRPC_PORT}:localhost:{GRPC_PORT}" in ssh
    )


def test_a_free_run_looks_at_the_hand_not_above_it(tmp_path):
    """A run holding no object aims the 3-D view inside the hand's own extent (palm to fingertips, in the
    hand's model at rest and closed), so the whole hand is framed."""
    import mujoco

    from twin.assets import SCENE_XML

    model = mujoco.MjModel.from_xml_path(str(SCENE_XML))
    data = mujoco.MjData(model)
    extents = []
    for closed in (0.0, 1.0):  # open, then every hinge at its upper limit
        data.qpos[:] = closed * model.jnt_range[:, 1]
        mujoco.mj_forward(model, data)
        hand = [
            g
            for g in range(model.ngeom)
            if model.body(model.geom_bodyid[g]).name.startswith(("f1", "f2", "f3", "palm"))
        ]
        reach = model.geom_rbound[hand, None]
        extents += [data.geom_xpos[hand] - reach, data.geom_xpos[hand] + reach]
    points = np.concatenate(extents)
    blueprint = read_rrd_blueprint(_saved(tmp_path, KINDS["free"]))
    (eye,) = [cols for path, cols in blueprint.items() if path.endswith("/EyeControls3D")]
    target = np.array(eye["EyeControls3D:look_target"][0])
    assert (points.min(axis=0) - 1e-3 <= target).all() and (target <= points.max(axis=0) + 1e-3).all()
