"""One contract for every backend (as Gymnasium checks every environment): specs readable before
connect, no reading without a connection, readings shaped, typed and bounded as declared."""

import numpy as np
import pytest
from twin.hardware.backend import HardwareBackend

from twin.interface.backend import Backend
from twin.interface.devices import HandCommand, HandReading
from twin.interface.errors import DeviceNotConfiguredError, DeviceNotConnectedError
from twin.sim.backend import SimBackend
from twin.sim.foam import LIBRARY

BACKENDS = {
    "sim": lambda: SimBackend(LIBRARY["block"], seed=3),
    "hardware": HardwareBackend,
}


@pytest.fixture(params=sorted(BACKENDS))
def backend(request) -> Backend:
    return BACKENDS[request.param]()


def test_spec_is_readable_before_connect(backend: Backend):
    spec = backend.hand.spec
    assert spec.rate_hz > 0 and 0 <= spec.latency_s < spec.period_s
    assert set(spec.channels) == {"position_counts", "velocity_counts", "strain_counts"}
    assert spec.channels["strain_counts"].saturation == (0, 255)


def test_hand_refuses_to_work_unconnected(backend: Backend):
    with pytest.raises(DeviceNotConnectedError, match="not connected"):
        backend.hand.read()
    with pytest.raises(DeviceNotConnectedError):
        backend.hand.command(HandCommand(np.zeros(4)))


def test_connect_gives_readings_as_declared_or_a_clear_error(backend: Backend):
    if backend.name == "hardware":
        with pytest.raises(DeviceNotConfiguredError, match="no BH8 hand is configured"):
            backend.connect()
        assert not backend.hand.is_connected
        return
    backend.connect()
    try:
        for _ in range(3):
            backend.clock.advance_to(backend.clock.now() + backend.hand.spec.period_s)
            reading = backend.hand.read()
            assert isinstance(reading, HandReading)
            for name, channel in backend.hand.spec.channels.items():
                value = getattr(reading, name)
                assert value.shape == channel.shape, name
                assert value.dtype == np.dtype(channel.dtype), name
                lo, hi = channel.saturation
                assert ((value >= lo) & (value <= hi)).all(), name
    finally:
        backend.disconnect()
    assert not backend.hand.is_connected


def test_command_is_clipped_to_the_firmware_range():
    backend = SimBackend(None)
    backend.connect()
    applied = backend.hand.command(HandCommand(np.array([-50.0, 99_999.0, 5_000.0, 9_999.0]), 1e9))
    assert applied.position_counts.tolist() == [0.0, 17_800.0, 5_000.0, 3_140.0]
    assert applied.max_velocity_counts_s == backend.hand.config.max_velocity_counts_s


def test_sim_is_deterministic_for_a_seed():
    def trace(seed: int) -> list[np.ndarray]:
        b = SimBackend(LIBRARY["soft_block"], seed=seed)
        b.connect()
        b.hand.command(HandCommand(np.array([9000.0, 9000.0, 9000.0, 0.0]), 6000))
        out = []
        for k in range(1, 20):
            b.clock.advance_to(k * 0.05)
            r = b.hand.read()
            out.append(np.concatenate([r.position_counts, r.velocity_counts, r.strain_counts]))
        return out

    assert np.array_equal(trace(7), trace(7))
    assert not np.array_equal(trace(7), trace(8))  # the seed drives the strain-gauge noise
