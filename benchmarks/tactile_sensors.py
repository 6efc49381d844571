"""Which way to simulate the pads: MuJoCo's `tactile` sensor, the `touch_grid` plugin, or binning
contact forces over the taxels (twin/sim/tactile.py)? Criteria from the tactile issue: force balance
(the pad's total against the load) on a rigid and on a flexcomp object, and cost.

A 18x48 mm pad (a 3x8 finger pad of 6 mm cells) presses with a known force on a rigid box and on a
trilinear flexcomp block; after settling, each method's total over the pad is compared with the
applied load, and the cost is timed.
"""

from __future__ import annotations

import time

import mujoco
import numpy as np

LOAD_N = 5.0
_XML = """
<mujoco>
  <extension><plugin plugin="mujoco.sensor.touch_grid"/></extension>
  <option timestep="0.002"/>
  <asset><mesh name="padmesh" vertex="-0.009 -0.024 -0.005  0.009 -0.024 -0.005  0.009 0.024 -0.005
    -0.009 0.024 -0.005  -0.009 -0.024 0.005  0.009 -0.024 0.005  0.009 0.024 0.005  -0.009 0.024 0.005"/>
  </asset>
  <worldbody>
    <body name="pad" pos="0 0 0.08"><joint name="z" type="slide" axis="0 0 1"/>
      <geom name="padg" type="box" size="0.009 0.024 0.005" mass="0.05"/>
      <site name="padsite" zaxis="0 0 1"/>
    </body>
    {object}
    <geom type="plane" size="0.2 0.2 0.01"/>
  </worldbody>
  <actuator><motor joint="z" gear="1"/></actuator>
  <sensor>
    {sensors}
  </sensor>
</mujoco>"""
_TOUCH_GRID = """<plugin name="grid" plugin="mujoco.sensor.touch_grid" objtype="site" objname="padsite">
      <config key="size" value="3 8"/><config key="fov" value="80 85"/><config key="gamma" value="0"/>
      <config key="nchannel" value="1"/></plugin>"""
_TACTILE = '<tactile name="tactile" geom="padg" mesh="padmesh"/>'
OBJECTS = {
    "rigid box": """<body pos="0 0 0.03"><freejoint/>
      <geom type="box" size="0.025 0.025 0.025" mass="0.1"/></body>""",
    "flexcomp foam": """<flexcomp name="foam" type="grid" count="4 4 4" spacing="0.016 0.016 0.016"
      pos="0 0 0.03" dim="3" dof="trilinear" radius="0.001" mass="0.1">
      <elasticity young="4e4" poisson="0.3" damping="0.002"/>
      <contact condim="3" solref="0.01 1" selfcollide="none"/><edge equality="false"/></flexcomp>""",
}


def _settle(sensors: str, obj: str, steps: int) -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_string(_XML.format(object=obj, sensors=sensors))
    data = mujoco.MjData(model)
    data.ctrl[0] = -LOAD_N
    for _ in range(steps):
        mujoco.mj_step(model, data)
    return model, data


def _binned_total(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """What binning sums over the pad: the normal force of every contact on the pad's body."""
    pad = model.body("pad").id
    total, wrench = 0.0, np.zeros(6)
    for i in range(data.ncon):
        c = data.contact[i]
        if pad in (model.geom_bodyid[g] if g >= 0 else -1 for g in c.geom):
            mujoco.mj_contactForce(model, data, i, wrench)
            total += wrench[0]
    return total


def _step_us(model: mujoco.MjModel, data: mujoco.MjData, steps: int) -> float:
    t0 = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(model, data)
    return (time.perf_counter() - t0) / steps * 1e6


def run(quick: bool = False) -> dict:
    """Force totals and costs per method and object."""
    settle, timed = (1500, 300) if quick else (3000, 2000)
    rows = []
    for name, obj in OBJECTS.items():
        model, data = _settle(f"{_TOUCH_GRID}\n{_TACTILE}", obj, settle)
        expected = LOAD_N + float(model.body_mass[model.body("pad").id]) * 9.81
        grid = data.sensordata[model.sensor_adr[0] : model.sensor_adr[0] + model.sensor_dim[0]]
        tactile = data.sensordata[model.sensor_adr[1] : model.sensor_adr[1] + model.sensor_dim[1]]
        bare_model, bare_data = _settle("", obj, settle)
        t0 = time.perf_counter()
        for _ in range(timed):
            _binned_total(bare_model, bare_data)
        rows.append(
            {
                "object": name,
                "load_n": expected,
                "binning_n": _binned_total(bare_model, bare_data),
                "touch_grid_n": float(grid.sum()),
                "touch_grid_cells": int(np.count_nonzero(grid > 0)),
                "tactile_sum": float(tactile.sum()),
                "tactile_nonzero": int(np.count_nonzero(tactile)),
                "step_us_bare": _step_us(bare_model, bare_data, timed),
                "step_us_sensors": _step_us(model, data, timed),
                "binning_us_per_scan": (time.perf_counter() - t0) / timed * 1e6,
            }
        )
    return {"rows": rows}


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    lines = [
        "## Tactile simulation: native sensors vs contact binning",
        "",
        f"A pad presses {LOAD_N:g} N (+ its weight) on a rigid box and on a trilinear flexcomp block "
        "(`benchmarks/tactile_sensors.py`). Totals over the pad after settling; costs per physics step "
        "(sensors are computed every step) and per scan (binning runs only at the 30 Hz scan).",
        "",
        "| object | load (N) | binning (N) | touch_grid total (N), cells > 0 | tactile sensor sum, nonzero |"
        " step, bare (us) | step with both sensors (us) | contact-force total per scan, python loop (us) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r['object']} | {r['load_n']:.3f} | {r['binning_n']:.3f} | {r['touch_grid_n']:.3f}, "
            f"{r['touch_grid_cells']} | {r['tactile_sum']:.3g}, {r['tactile_nonzero']} | "
            f"{r['step_us_bare']:.0f} | {r['step_us_sensors']:.0f} | {r['binning_us_per_scan']:.0f} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
