"""The Rerun module against real Rerun and MuJoCo: what is logged reads back with Rerun's reader."""

import mujoco
import numpy as np
import pytest

from twin.viz.rerun_log import RunRecording, default_blueprint, read_rrd_entities, read_rrd_scalars

XML = """
<mujoco>
  <option integrator="discrete" timestep="0.002"/>
  <worldbody>
    <geom type="plane" size="1 1 .1"/>
    <body name="arm" pos="0 0 .3">
      <joint type="hinge" axis="0 1 0"/>
      <geom name="link" type="capsule" fromto="0 0 0 .1 0 0" size=".01"/>
      <geom name="hidden" type="box" size=".01 .01 .01" group="3"/>
    </body>
    <flexcomp name="foam" type="grid" count="3 3 3" spacing=".02 .02 .02" pos="0 0 .1" dim="3"
              radius=".001" dof="trilinear" mass=".05">
      <elasticity young="5e4" poisson="0.3" damping="0.001"/>
      <contact selfcollide="none"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""


def test_model_scene_and_scalars_read_back(tmp_path):
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    path = tmp_path / "run.rrd"
    logged = []
    with RunRecording(path, recording_id="test") as rec:
        rec.log_model(model)
        for i in range(50):
            mujoco.mj_step(model, data)
            rec.log_scene(data.time, data)
            values = {"torque_nm": np.array([i, 2 * i, 3 * i], float), "phase": float(i % 3)}
            rec.log_scalars("hand", data.time, values, labels={"torque_nm": ["F1", "F2", "F3"]})
            logged.append((data.time, values["torque_nm"]))
        rec.log_text(data.time, "done")
    entities = read_rrd_entities(path)
    assert entities["/world/flex/foam"] == 50
    assert entities["/world/bodies/arm"] >= 50
    assert "/world/bodies/arm/link" in entities
    assert "/world/bodies/arm/hidden" not in entities  # collision group is not drawn
    times, torque = read_rrd_scalars(path, "/plots/hand/torque_nm")
    assert torque.shape == (50, 3)
    assert times == pytest.approx([t for t, _ in logged])
    assert torque == pytest.approx(np.array([v for _, v in logged]))
    _, phase = read_rrd_scalars(path, "/plots/hand/phase")
    assert phase.shape == (50,)


def test_blueprint_builds_and_close_is_idempotent(tmp_path):
    assert default_blueprint(streams=("hand", "tactile")) is not None
    rec = RunRecording(tmp_path / "x.rrd")
    rec.close()
    rec.close()
    with pytest.raises(KeyError):
        read_rrd_scalars(tmp_path / "x.rrd", "/plots/none")
