"""The compress procedure on synthetic readings, with no backend at all: it only sees counts and
strain, so it runs unchanged on the twin or the real hand."""

import math

import numpy as np
import pytest

from experiments.compress import CompressController, CompressProfile
from twin import units
from twin.interface.devices import HandReading
from twin.interface.errors import ConfigError


class ToyHand:
    """Fingers that move to their set points; distal torque grows past a contact position."""

    def __init__(self, contact_counts=(9000.0, 9500.0, 10000.0), stiffness_nm_per_count=0.001):
        self.position = np.zeros(3)
        self.contact = np.array(contact_counts)
        self.k = stiffness_nm_per_count

    def reading(self, t_s: float) -> HandReading:
        torque = self.k * np.clip(self.position - self.contact, 0, None)
        strain = np.round(units.torque_nm_to_strain(torque)).astype(np.int32)
        counts = np.append(np.round(self.position), 0).astype(np.int32)
        return HandReading(t_s, counts, np.zeros(4, np.int32), strain)

    def apply(self, target: np.ndarray, max_velocity: float, dt: float) -> None:
        step = max_velocity * dt
        self.position += np.clip(target[:3] - self.position, -step, step)


def drive(controller: CompressController, hand: ToyHand, seconds: float, rate_hz: float = 30.0):
    dt = 1 / rate_hz
    log = []
    for k in range(int(seconds * rate_hz)):
        command = controller(hand.reading(k * dt))
        hand.apply(command.position_counts, command.max_velocity_counts_s, dt)
        log.append((k * dt, controller.phase, command.position_counts[:3].copy()))
    return log


def test_close_stops_each_finger_at_contact_then_balances_then_compresses():
    profile = CompressProfile()
    controller, hand = CompressController(profile), ToyHand()
    log = drive(controller, hand, 12.0)
    phases = [p for _, p, _ in log]
    assert phases[0] == "close" and phases[-1] == "compress"
    assert phases.index("balance") < phases.index("compress")
    # Balanced: every finger sits at the grasp torque, whatever its own contact position.
    grasp_torque = hand.k * (controller.grasp_counts - hand.contact)
    assert grasp_torque == pytest.approx(np.full(3, profile.grasp_torque_nm), abs=0.01)
    # Compression follows offset + amplitude sin(omega t + phase) about the grasp, in counts.
    t0 = next(t for t, p, _ in log if p == "compress")
    for t, phase, target in log:
        if phase == "compress" and t > t0:
            wave = profile.offset_counts + profile.amplitude_counts * math.sin(
                2 * math.pi * profile.frequency_hz * (t - t0) + profile.phase_rad
            )
            assert target == pytest.approx(controller.grasp_counts + wave)


def test_nothing_to_grasp_times_out_into_balance():
    controller = CompressController(CompressProfile(close_timeout_s=2.0))
    log = drive(controller, ToyHand(contact_counts=(1e9, 1e9, 1e9)), 3.0)
    assert log[-1][1] == "balance"


@pytest.mark.parametrize(
    "kwargs",
    [{"grasp_torque_nm": 0}, {"frequency_hz": 0}, {"offset_counts": 3000, "amplitude_counts": 2000}],
)
def test_bad_profiles_are_refused(kwargs):
    with pytest.raises(ConfigError, match="compress"):
        CompressProfile(**kwargs)
