"""The public API end to end: a researcher's own controller, written against `twin` alone, runs on the
twin and on the emulated hand (the `bh8emu://` URL, wall time, the real driver), and both runs read back."""

from pathlib import Path

import numpy as np
import pytest

import twin
from twin import HandCommand, HandReading, units
from twin.interface.errors import ConfigError, TwinError


class CloseUntilTouch:
    """Close the three fingers; hold each where its distal torque (eq. 2) rises 0.1 N*m over its first."""

    phase = "close"

    def __init__(self) -> None:
        self.baseline: np.ndarray | None = None
        self.hold = np.full(3, float(units.FINGER_FULL_COUNTS))
        self.touched_at: dict[int, float] = {}

    def __call__(self, reading: HandReading) -> HandCommand:
        torque = units.strain_to_torque_nm(reading.strain_counts)
        if self.baseline is None:
            self.baseline = torque
        new = (torque - self.baseline > 0.1) & (self.hold == units.FINGER_FULL_COUNTS)
        self.hold[new] = reading.position_counts[:3][new]
        self.touched_at.update({int(k): reading.t_s for k in np.flatnonzero(new)})
        if len(self.touched_at) == 3:
            self.phase = "hold"
        return HandCommand(np.append(self.hold, 0.0), max_velocity_counts_s=5000.0)


def _check(run: twin.Run, controller: CloseUntilTouch, backend: str) -> np.ndarray:
    """The run as recorded: complete, its commands the controller's, phases switched; the held counts."""
    assert run.status == "complete"
    assert run.metadata["backend"] == backend
    assert run.metadata["experiment"]["name"] == "squeeze-and-hold"
    assert run.metadata["phases"] == ["close", "hold"]
    hand, command = run.stream("hand"), run.stream("command")
    assert len(hand) == len(command) == 91  # 3 s at 30 Hz, both ends
    # One clock (issue 37): each command answers the reading just before it and goes out before the
    # next reading is taken, however late the loop runs on wall time
    assert np.all(hand.t_s <= command.t_s) and np.all(command.t_s[:-1] < hand.t_s[1:])
    assert set(np.unique(command["phase"])) == {0, 1}
    # every finger touched, and the last command holds it where the controller saw the touch: the
    # recorded reading of that instant (the hand stream and the controller saw the same samples)
    assert sorted(controller.touched_at) == [0, 1, 2]
    held = command["position_counts"][-1, :3]
    assert np.array_equal(held, controller.hold)
    for finger, t_s in controller.touched_at.items():
        (at,) = np.flatnonzero(hand.t_s == t_s)
        assert hand["position_counts"][at, finger] == held[finger]
    assert (held < units.FINGER_FULL_COUNTS).all() and (held > 5000).all()
    # the hand stopped near its hold (the foam pushes back less than the drive's stall)
    assert np.abs(hand["position_counts"][-1, :3] - held).max() < 300
    return held


def test_a_custom_controller_runs_on_the_twin_and_on_the_emulated_hand(tmp_path: Path):
    on_sim, on_hw = CloseUntilTouch(), CloseUntilTouch()
    a = twin.run(
        twin.sim_backend("block", seed=1), on_sim, duration_s=3, out=tmp_path / "sim",
        name="squeeze-and-hold", phases=("close", "hold"),
    )  # fmt: skip
    b = twin.run(
        twin.hardware_backend(hand="bh8emu://?object=block"), on_hw, duration_s=3, out=tmp_path / "hw",
        name="squeeze-and-hold", phases=("close", "hold"), object_name="block",
    )  # fmt: skip
    assert a.status == b.status == "complete"
    _check(twin.open_run(a.run_dir), on_sim, "sim")
    _check(twin.open_run(b.run_dir), on_hw, "hardware")
    # (Where the fingers meet the block on wall time depends on how late a loaded host runs the loop:
    # a reading 2 periods late is 330 counts at 5000 counts/s. benchmarks/camera_bridge.py measures
    # how closely a hardware run follows the twin's.)
    assert (tmp_path / "sim" / "run.rrd").stat().st_size > 0 and (tmp_path / "hw" / "run.rrd").is_file()
    assert "tactile" in twin.open_run(a.run_dir).streams  # the sim's pads, recorded as the CLI records them


def test_the_safety_layer_stops_an_unsafe_controller_and_the_run_says_so(tmp_path: Path):
    def too_far(reading: HandReading) -> HandCommand:
        target = 20_000.0 if reading.t_s > 0.5 else 1000.0  # past the firmware's finger range
        return HandCommand(np.array([target, 1000.0, 1000.0, 0.0]))

    with pytest.raises(TwinError, match="outside"):
        twin.run(twin.sim_backend("block"), too_far, duration_s=2, out=tmp_path / "r")
    run = twin.open_run(tmp_path / "r")
    assert run.status == "failed"
    assert run.metadata["stop"]["idle"] == "acknowledged"
    commands = run.stream("command")["position_counts"]
    assert len(commands) > 10 and commands[:, :3].max() == 1000.0  # the unsafe one never reached the hand


def test_a_controller_that_returns_something_else_is_refused_in_one_line(tmp_path: Path):
    with pytest.raises(ConfigError, match="returned list, not a HandCommand"):
        twin.run(twin.sim_backend(None), lambda r: [0, 0, 0, 0], duration_s=1, out=tmp_path / "r")
    with pytest.raises(ConfigError, match="must be callable"):
        twin.run(twin.sim_backend(None), "close", duration_s=1, out=tmp_path / "s")
    assert not (tmp_path / "s").exists()
