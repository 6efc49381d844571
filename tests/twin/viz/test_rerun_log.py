"""The Rerun module against real Rerun and MuJoCo: what is logged reads back with Rerun's reader."""

import mujoco
import numpy as np
import pytest

from twin.viz.rerun_log import (
    RunRecording,
    read_rrd_entities,
    read_rrd_meshes,
    read_rrd_scalars,
    read_rrd_views,
)

# Default (Euler) integrator: flex elasticity is not supported by implicitfast.
XML = """
<mujoco>
  <option timestep="0.002"/>
  <asset>
    <material name="steel" rgba=".3 .3 .35 1"/>
    <mesh name="tet" vertex="0 0 0  .02 0 0  0 .02 0  0 0 .02"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 .1"/>
    <geom name="table" type="box" size=".2 .2 .01" pos="0 0 -.01" material="steel"/>
    <body name="arm" pos="0 0 .3">
      <joint type="hinge" axis="0 1 0"/>
      <geom name="link" type="capsule" fromto="0 0 0 .1 0 0" size=".01"/>
      <geom name="block" type="box" size=".01 .02 .03" pos=".1 0 0" material="steel"/>
      <geom name="tip" type="mesh" mesh="tet" pos=".12 0 0"/>
      <geom name="hidden" type="box" size=".01 .01 .01" group="3"/>
      <geom name="invisible" type="sphere" size=".01" rgba="1 0 0 0"/>
    </body>
    <body name="pusher" mocap="true" pos=".3 0 .2">
      <geom type="sphere" size=".01" contype="0" conaffinity="0"/>
    </body>
    <flexcomp name="foam" type="grid" count="3 3 3" spacing=".02 .02 .02" pos="0 0 .1" dim="3"
              radius=".001" dof="trilinear" mass=".05">
      <elasticity young="5e4" poisson="0.3" damping="0.001"/>
      <contact selfcollide="none"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""
STEPS = 50


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """50 steps of the model logged to an .rrd; what was logged, to compare with what reads back."""
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    logged = {"t": [], "torque": [], "phase": [], "foam": []}
    with RunRecording(path, recording_id="test") as rec:
        rec.log_model(model)
        for i in range(STEPS):
            data.mocap_pos[0, 2] -= 1e-3
            mujoco.mj_step(model, data)
            rec.log_scene(data.time, data)
            torque = np.array([i, 2 * i, 3 * i], float) / 7
            values = {"torque_nm": torque, "phase": i % 3}
            rec.log_scalars("hand", data.time, values, labels={"torque_nm": ["F1", "F2", "F3"]})
            logged["t"].append(data.time)
            logged["torque"].append(torque)
            logged["phase"].append(i % 3)
            logged["foam"].append(data.flexvert_xpos.copy())
        rec.log_text(data.time, "done")
    return path, {k: np.array(v) for k, v in logged.items()}


def test_model_geoms_are_static_entities_under_their_bodies(run):
    entities = read_rrd_entities(run[0])
    for geom in ("arm/link", "arm/block", "arm/tip", "world/table", "pusher/geom_7"):
        assert f"/world/bodies/{geom}" in entities
    # Collision group, fully transparent and plane geoms are not drawn.
    for geom in ("arm/hidden", "arm/invisible", "world/floor"):
        assert f"/world/bodies/{geom}" not in entities
    assert entities["/log"] == 1


def test_scene_body_poses_and_foam_mesh_every_step(run):
    path, logged = run
    entities = read_rrd_entities(path)
    assert entities["/world/bodies/arm"] == STEPS
    assert entities["/world/bodies/pusher"] == STEPS  # mocap: no joint, yet it moves
    assert entities["/world/flex/foam"] == STEPS + 1  # the triangles and colour once, static
    meshes = read_rrd_meshes(path, "/world/flex/foam")
    assert len(meshes) == STEPS
    verts, faces, normals = meshes[-1]
    assert verts.shape == normals.shape == (27, 3)
    np.testing.assert_allclose(verts, logged["foam"][-1], atol=1e-6)
    # The foam falls: the logged frames differ, each one is its own step.
    assert not np.allclose(logged["foam"][0], logged["foam"][-1])
    np.testing.assert_allclose(meshes[0][0], logged["foam"][0], atol=1e-6)
    # The surface of a 3x3x3 grid: 6 sides of 2x2 squares of 2 triangles, closed (each edge twice),
    # wound outwards; the 1x1x1 centre vertex is inside.
    assert faces.shape == (48, 3)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    assert set(np.unique(edges, axis=0, return_counts=True)[1]) == {2}
    assert 13 not in faces
    a, b, c = (verts[faces[:, i]] for i in range(3))
    outward = np.einsum("ij,ij->i", np.cross(b - a, c - a), (a + b + c) / 3 - verts.mean(axis=0))
    assert (outward > 0).all()
    # Unit vertex normals for shading, pointing out of the foam at its surface.
    surface = np.unique(faces)
    np.testing.assert_allclose(np.linalg.norm(normals[surface], axis=1), 1, atol=1e-5)
    assert (np.einsum("ij,ij->i", normals[surface], verts[surface] - verts.mean(axis=0)) > 0).all()


def test_scalars_read_back_as_logged(run):
    path, logged = run
    times, torque = read_rrd_scalars(path, "/plots/hand/torque_nm")
    assert torque.shape == (STEPS, 3)  # one entity, three series
    np.testing.assert_allclose(times, logged["t"], atol=1e-9)
    np.testing.assert_allclose(torque, logged["torque"])
    times, phase = read_rrd_scalars(path, "plots/hand/phase")
    assert phase.shape == (STEPS,)
    np.testing.assert_array_equal(phase, logged["phase"])
    with pytest.raises(KeyError):
        read_rrd_scalars(path, "/plots/hand/nothing")
    with pytest.raises(KeyError):
        read_rrd_scalars(path, "/plots/hand/phase", timeline="wall_time")


def test_series_no_view_names_get_a_view_of_their_own(tmp_path):
    path = tmp_path / "bp.rrd"
    with RunRecording(path) as rec:
        rec.log_scalars("hand", 0.0, {"torque_nm": [1.0, 2.0, 3.0]})
        rec.log_scalars("pump", 0.0, {"pressure_kpa": 3.0})
    views = read_rrd_views(path)
    assert views["strain-gauge torque, eq. 2 (N·m)"]["contents"] == ["/plots/hand/torque_nm"]
    assert views["other series"]["contents"] == ["/plots/pump/pressure_kpa"]


def test_close_is_idempotent_and_final(tmp_path):
    rec = RunRecording(tmp_path / "x.rrd")
    rec.close()
    rec.close()
    with pytest.raises(RuntimeError):
        rec.log_text(0.0, "too late")
    assert "/plots/none" not in read_rrd_entities(tmp_path / "x.rrd")
    with pytest.raises(FileNotFoundError):
        read_rrd_entities(tmp_path / "missing.rrd")


def test_labels_must_match_the_series(tmp_path):
    with RunRecording(tmp_path / "x.rrd") as rec, pytest.raises(ValueError, match="2 labels for 3"):
        rec.log_scalars("hand", 0.0, {"torque_nm": [1, 2, 3]}, labels={"torque_nm": ["F1", "F2"]})


def test_surface_and_cable_flexes(tmp_path):
    xml = """
    <mujoco><worldbody>
      <flexcomp name="sheet" type="grid" count="4 3 1" spacing=".02 .02 .02" dim="2" radius=".001"
                mass=".05"><edge equality="true"/></flexcomp>
      <flexcomp name="cable" type="grid" count="5 1 1" spacing=".02 .02 .02" pos="0 .3 0" dim="1"
                radius=".001" mass=".05"><edge equality="true"/></flexcomp>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    path = tmp_path / "flex.rrd"
    with RunRecording(path) as rec:
        rec.log_model(model)
        rec.log_scene(0.0, data)
    ((verts, faces, _),) = read_rrd_meshes(path, "/world/flex/sheet")
    assert verts.shape == (12, 3)
    assert faces.shape == (2 * 3 * 2, 3)
    assert read_rrd_entities(path)["/world/flex/cable"] == 1


def test_a_finger_at_the_force_cap_is_an_event_a_warning_and_a_line_on_the_force_plot(tmp_path):
    """The safety layer stops a finger at the 2 kg fingertip-force cap from closing: the recording says
    when (a state lane per finger, a warning row on entering) and draws the cap on the force plot."""
    import rerun as rr

    from twin.viz.rerun_log import _rows

    path = tmp_path / "cap.rrd"
    forces = [(0.0, [0.5, 0.5, 1.9]), (0.1, [0.6, 0.5, 2.0]), (0.2, [0.6, 0.5, 2.3]), (0.3, [2.1, 0.5, 1.2])]
    with RunRecording(path) as rec:
        rec.log_command(0.0, [1000, 1000, 1000], "compress")
        for t, force in forces:
            physical = {"velocity_rad_s": np.zeros(4), "torque_nm": np.zeros(3), "force_kg": np.array(force)}
            rec.log_hand(t, np.array([5000, 5000, 5000, 0]), np.zeros(3), physical)
    state = rr.StateChange.descriptor_state().component
    lanes = {
        finger: [(t, cells[state]) for t, cells in _rows(path, f"events/{finger}_force_cap", [state])]
        for finger in ("F1", "F2", "F3")
    }
    assert lanes["F3"] == [(0.1, ["at the 2 kg cap"]), (0.3, [])]  # entered at 2.0 kg, cleared at 1.2
    assert lanes["F1"] == [(0.3, ["at the 2 kg cap"])] and lanes["F2"] == []
    assert [cells[state] for _, cells in _rows(path, "events/phase", [state])] == [["compress"]]
    text, level = rr.TextLog.descriptor_text().component, rr.TextLog.descriptor_level().component
    warnings = [cells[text][0] for _, cells in _rows(path, "log", [text, level]) if cells[level] == ["WARN"]]
    assert [w.split(" ", 1)[0] for w in warnings] == ["F3", "F1"]
    _, cap = read_rrd_scalars(path, "plots/hand/force_cap_kg")
    assert np.allclose(cap, 2.0) and len(cap) == len(forces)
