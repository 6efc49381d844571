"""Commands outside the limits never reach the wire: a property test through the safety layer and
the serial hand, checked on what the emulated hand actually received."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from twin.hardware.backend import WallClock
from twin.hardware.bh262.driver import PortSettings
from twin.hardware.bh262.emulator import make_hand_emulator
from twin.hardware.bh262.hand import BH8SerialHand

from twin.interface.devices import HandCommand
from twin.interface.hand_spec import HandConfig
from twin.safety import SafetyLayer, SafetyLimits, UnsafeCommandError

LIMITS = SafetyLimits(
    finger_counts=(500.0, 15_000.0), spread_counts=(0.0, 1_000.0), max_velocity_counts_s=5_000.0
)


@pytest.fixture(scope="module")
def wired():
    with make_hand_emulator(None) as emulator:
        port = PortSettings(url=emulator.serve_tcp(0), switch_baud=38400, baud_switch_wait_s=0.05)
        hand = BH8SerialHand(HandConfig(), port, WallClock())
        hand.connect()
        yield hand, emulator.firmware, SafetyLayer(LIMITS)
        hand.disconnect()


counts = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-1000, 20_000),
    st.sampled_from([0.0, 499.9, 500.0, 15_000.0, 15_000.1, 17_800.0]),
)
velocity = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-100, 20_000))


@settings(max_examples=300, deadline=None)
@given(st.lists(counts, min_size=4, max_size=4), velocity)
def test_commands_outside_the_limits_never_reach_the_wire(wired, position, max_velocity):
    hand, firmware, safety = wired
    safety.observe(hand.read())
    before = firmware.controls_received
    command = HandCommand(np.array(position), max_velocity)
    try:
        sent = safety.check(command)
    except UnsafeCommandError:
        assert firmware.controls_received == before  # refused: not a byte of control went out
        return
    fingers, spread = np.asarray(position[:3]), position[3]
    assert np.all((fingers >= 500) & (fingers <= 15_000)) and 0 <= spread <= 1_000
    assert math.isfinite(max_velocity) and 0 < max_velocity <= 5_000
    hand.command(sent)
    assert firmware.controls_received == before + 1
    for motor, values in firmware.last_control.items():  # what the hand received, motor by motor
        speed = abs(values["LCV"]) * firmware.props[motor]["LCVC"] / firmware.options.velocity_unit_s
        assert speed <= max_velocity
    setpoint = hand._setpoint
    assert np.all(setpoint >= 0) and np.all(setpoint[:3] <= 17_800)
