"""The safety layer: nothing outside the limits reaches a device (property tests), and the rig
routes every command through it on a real simulated hand."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twin import units
from twin.interface.devices import HandCommand, HandReading
from twin.rig import Rig
from twin.safety import SafetyLayer, SafetyLimits, UnsafeCommandError
from twin.sim.backend import SimBackend
from twin.sim.foam import LIBRARY

LIMITS = SafetyLimits()
anything = st.floats(allow_nan=True, allow_infinity=True, width=64)
near_range = st.floats(-2000, 20_000)
positions = st.lists(st.one_of(anything, near_range), min_size=4, max_size=4)
velocities = st.one_of(anything, st.floats(-100, 20_000))
readings = st.builds(
    lambda pos, strain: HandReading(
        0.0, np.array(pos, np.int32), np.zeros(4, np.int32), np.array(strain, np.int32)
    ),
    st.lists(st.integers(0, 17_800), min_size=4, max_size=4),
    st.lists(st.integers(0, 255), min_size=3, max_size=3),
)


def within_limits(cmd: HandCommand) -> bool:
    p, v = cmd.position_counts, cmd.max_velocity_counts_s
    lo, hi = LIMITS.finger_counts
    return (
        bool(np.isfinite(p).all())
        and math.isfinite(v)
        and bool(((p[:3] >= lo) & (p[:3] <= hi)).all())
        and LIMITS.spread_counts[0] <= p[3] <= LIMITS.spread_counts[1]
        and 0 < v <= LIMITS.max_velocity_counts_s
    )


@pytest.mark.slow
@settings(max_examples=3000, deadline=None)
@given(positions, velocities, st.one_of(st.none(), readings))
def test_nothing_outside_the_limits_gets_through(pos, velocity, reading):
    layer = SafetyLayer(LIMITS)
    if reading is not None:
        layer.observe(reading)
    command = HandCommand(np.array(pos), velocity)
    try:
        sent = layer.check(command)
    except UnsafeCommandError:
        assert not within_limits(command)
        return
    assert within_limits(sent)
    if reading is not None:
        # A finger at the 2 kg limit never closes beyond where it is.
        at_limit = units.strain_to_force_kg(reading.strain_counts) >= LIMITS.max_fingertip_force_kg
        assert (sent.position_counts[:3][at_limit] <= reading.position_counts[:3][at_limit]).all()


class SpyHand:
    """Wraps a real SimHand and remembers every command that reached it."""

    def __init__(self, hand):
        self.hand, self.sent = hand, []
        self._command = hand.command
        hand.command = self.command

    def command(self, command):
        self.sent.append(command)
        return self._command(command)


def test_rig_refuses_a_nan_command_before_the_hand_sees_it():
    backend = SimBackend(None)
    backend.connect()
    spy = SpyHand(backend.hand)

    class GoesNaN:
        phase = "close"
        n = 0

        def __call__(self, reading):
            self.n += 1
            target = math.nan if self.n == 10 else 2000.0
            return HandCommand(np.array([target, 2000.0, 2000.0, 0.0]), 5000)

    with pytest.raises(UnsafeCommandError, match="non-finite"):
        Rig(backend).run(GoesNaN(), duration_s=2.0)
    assert len(spy.sent) == 9
    assert all(np.isfinite(c.position_counts).all() for c in spy.sent)


def test_fingers_at_the_force_limit_are_held():
    backend = SimBackend(LIBRARY["firm_block"], seed=1)
    backend.connect()
    spy = SpyHand(backend.hand)
    layer = SafetyLayer()
    readings = []

    class SqueezeHard:
        phase = "close"

        def __call__(self, reading):
            readings.append(reading)
            return HandCommand(np.array([17_000.0, 17_000.0, 17_000.0, 0.0]), 6000)

    Rig(backend, safety=layer).run(SqueezeHard(), duration_s=4.0)
    forces = np.array([units.strain_to_force_kg(r.strain_counts) for r in readings])
    assert (forces >= 2.0).any(), "the motors stall at the 2 kg limit, so some reading reaches it"
    for reading, force, sent in zip(readings, forces, spy.sent, strict=True):
        held = force >= 2.0
        assert (sent.position_counts[:3][held] <= reading.position_counts[:3][held]).all()
