"""The PPS tactile driver end to end against the emulator over TCP, a pty and ppsemu://: every frame
arrives once and in order, each injected fault has its outcome, bad ports fail in one line."""

import socket
import time

import numpy as np
import pytest
from twin.hardware.backend import WallClock
from twin.hardware.pps.driver import PPSTactile, TactilePortLostError, TactileTimeoutError
from twin.hardware.pps.emulator import (
    FaultPlan,
    TactileEmulator,
    constant_source,
    make_tactile_emulator,
    ramp_source,
)

from twin.interface.devices import N_TAXELS, TactileReading
from twin.interface.errors import ConfigError, DeviceError, DeviceNotConnectedError
from twin.interface.tactile_spec import TactileConfig

FAULT_AT = 6  # the 6th frame of the session: 5 clean frames first


def driver(url: str, **kwargs) -> PPSTactile:
    return PPSTactile(TactileConfig(), url, WallClock(), **kwargs)


def readings_through(tactile: PPSTactile, sequence: int, timeout_s: float = 30.0) -> list[TactileReading]:
    """Every frame not yet taken (read_pending: none skipped, however late this thread is scheduled)
    until the given sequence number (or later) has arrived; `timeout_s` is a hang guard only."""
    out: list[TactileReading] = []
    deadline = time.monotonic() + timeout_s
    while not out or out[-1].sequence < sequence:
        assert time.monotonic() < deadline, f"sequence {sequence} never came: {[r.sequence for r in out]}"
        out += tactile.read_pending()
        time.sleep(0.005)
    return out


def expected_ramp(sequence: int) -> np.ndarray:
    """ramp_source's scan k has sequence k - 1."""
    return (np.arange(N_TAXELS) * 1000 + 97 * (sequence + 1)) % 32768


def one_line(exc: pytest.ExceptionInfo) -> str:
    message = str(exc.value)
    assert "\n" not in message and message
    return message


# --- streaming ----------------------------------------------------------------------------------


def test_counts_arrive_at_about_the_scan_rate_over_tcp():
    with make_tactile_emulator("ramp") as emulator:
        tactile = driver(emulator.serve_tcp(0))
        with tactile:
            first = tactile.read()
            readings = readings_through(tactile, first.sequence + 15)
            readings = [r for r in readings if r.sequence > first.sequence]
            assert tactile.is_connected
        assert not tactile.is_connected and tactile._thread is None  # the reader stopped
    seqs = [r.sequence for r in readings]
    assert seqs == list(range(first.sequence + 1, first.sequence + 16))
    assert all(np.array_equal(r.counts, expected_ramp(r.sequence)) for r in readings)
    assert all(r.dropped_frames == 0 and r.counts.shape == (N_TAXELS,) for r in readings)
    t = np.array([r.t_s for r in readings])
    assert np.all(np.diff(t) > 0)  # (the rate they arrive at is the host's, not the driver's)


def test_counts_arrive_over_a_pty_and_the_in_process_url():
    with TactileEmulator(constant_source(1234)) as emulator, driver(emulator.serve_pty()) as tactile:
        reading = tactile.read_next()
        assert np.all(reading.counts == 1234) and tactile.diagnostics()["frames"] >= 1
    with driver("ppsemu://?source=ramp&rate=60") as tactile:
        readings = readings_through(tactile, 5)
        assert readings[-1].dropped_frames == 0
        assert np.array_equal(readings[-1].counts, expected_ramp(readings[-1].sequence))


def test_read_returns_the_newest_frame_without_waiting():
    with driver("ppsemu://?source=ramp&rate=100") as tactile:
        time.sleep(0.1)
        a = tactile.read()
        b = tactile.read()
        assert b.sequence >= a.sequence and tactile.spec.name == "tactile"
        assert tactile.spec.channels["counts"].shape == (N_TAXELS,)


def test_sequence_wraps_without_counting_drops():
    with driver("ppsemu://?source=ramp&rate=100&first_sequence=65533") as tactile:
        readings = readings_through(tactile, 65535)
        readings += [tactile.read_next() for _ in range(3)]
    assert [r.sequence for r in readings][-4:] == [65535, 0, 1, 2]
    assert readings[-1].dropped_frames == 0 and tactile.sequence_restarts == 0


def test_source_counts_saturate_at_15_bits():
    with driver("ppsemu://?source=zeros") as tactile:
        assert np.all(tactile.read().counts == 0)
    with TactileEmulator(constant_source(40_000)) as emulator, driver(emulator.serve_tcp()) as tactile:
        assert np.all(tactile.read().counts == 32767)


def test_read_before_connect_is_refused():
    with pytest.raises(DeviceNotConnectedError):
        driver("ppsemu://").read()


# --- faults ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("fault", "dropped"),
    [
        ("garbage", 0),  # noise with a false sync before the frame: skipped, nothing lost
        ("partial", 1),  # half a frame, then the next one
        ("corrupt", 1),  # CRC fails
        ("drop", 1),  # never sent
    ],
)
def test_recoverable_faults_over_tcp(fault: str, dropped: int):
    emulator = make_tactile_emulator("ramp", faults=f"{fault}@{FAULT_AT}")
    with emulator, driver(emulator.serve_tcp(0)) as tactile:
        readings = readings_through(tactile, FAULT_AT + 3)  # sequence = session frame - 1 on TCP
        diagnostics = tactile.diagnostics()
    before = [r for r in readings if r.sequence < FAULT_AT - 1]
    after = [r for r in readings if r.sequence > FAULT_AT - 1]
    assert all(r.dropped_frames == 0 for r in before)
    assert all(r.dropped_frames == dropped for r in after)
    assert [r.sequence for r in after] == list(range(FAULT_AT, FAULT_AT + 4))
    assert all(np.array_equal(r.counts, expected_ramp(r.sequence)) for r in readings)
    assert diagnostics["dropped_frames"] == dropped
    if fault in ("garbage", "partial", "corrupt"):
        assert diagnostics["discarded_bytes"] > 0 and diagnostics["bad_frames"] >= 1
    else:
        assert diagnostics["discarded_bytes"] == 0 and diagnostics["bad_frames"] == 0


def test_stall_times_out_in_one_line_then_recovers():
    with make_tactile_emulator("ramp", faults=f"stall@{FAULT_AT}:0.6") as emulator:
        url = emulator.serve_tcp(0)
        with driver(url, timeout_s=0.2) as tactile:
            readings_through(tactile, FAULT_AT - 2)  # the last frame before the stall
            time.sleep(0.35)
            with pytest.raises(TactileTimeoutError) as err:
                tactile.read()
            assert url in one_line(err) and "no valid frame" in str(err.value)
            with pytest.raises(TactileTimeoutError):
                tactile.read_next(0.05)
            after = tactile.read_next(1.0)  # the stream resumes where it stopped
            assert after.sequence == FAULT_AT - 1 and after.dropped_frames == 0
            assert tactile.read().sequence >= after.sequence


@pytest.mark.parametrize("port", ["tcp", "pty"])
def test_vanishing_port_is_a_clear_error(port: str):
    with make_tactile_emulator("ramp", rate_hz=60, faults=f"vanish@{FAULT_AT + 3}") as emulator:
        url = emulator.serve_tcp(0) if port == "tcp" else emulator.serve_pty()
        tactile = driver(url)
        tactile.connect()
        with pytest.raises(TactilePortLostError) as err:
            while True:
                tactile.read_next(1.0)
        assert url in one_line(err)
        with pytest.raises(TactilePortLostError):  # and it stays lost
            tactile.read()
        tactile.disconnect()
        tactile.disconnect()  # twice is fine


def test_faults_over_a_pty_recover():
    """On a pty the session starts when the emulator does; the driver joins a moment later."""
    emulator = make_tactile_emulator("ramp", faults="garbage@12,corrupt@16,drop@20,partial@24")
    with emulator, driver(emulator.serve_pty()) as tactile:
        readings = readings_through(tactile, 26)  # sequence = frame - 1
        assert tactile.diagnostics()["bad_frames"] >= 3
    assert readings[-1].dropped_frames == 3
    assert all(np.array_equal(r.counts, expected_ramp(r.sequence)) for r in readings)
    assert {15, 19, 23}.isdisjoint(r.sequence for r in readings)


def test_failing_source_closes_the_port():
    calls = 0

    def source() -> np.ndarray:
        nonlocal calls
        calls += 1
        return np.zeros(N_TAXELS if calls < 4 else 5, dtype=int)

    with TactileEmulator(source, rate_hz=60) as emulator:
        tactile = driver(emulator.serve_tcp(0))
        tactile.connect()
        with pytest.raises(TactilePortLostError):
            while True:
                tactile.read_next(1.0)
        tactile.disconnect()
        assert "162 integer counts" in str(emulator.error)


# --- bad ports and bad configuration ------------------------------------------------------------


def test_bad_ports_fail_in_one_line():
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    for url in (f"socket://127.0.0.1:{port}", "/dev/does-not-exist", "ppsemu://?speed=9", "nope://x"):
        with pytest.raises(DeviceError) as err:
            driver(url).connect()
        assert "cannot open the tactile port" in one_line(err) and url in str(err.value)


def test_a_silent_or_noisy_port_times_out_on_connect():
    server = socket.create_server(("127.0.0.1", 0))
    url = f"socket://127.0.0.1:{server.getsockname()[1]}"
    try:
        tactile = driver(url, connect_timeout_s=0.3)
        with pytest.raises(TactileTimeoutError) as err:
            tactile.connect()  # accepted by the kernel, never a byte
        assert url in one_line(err) and "streaming" in str(err.value) and not tactile.is_connected
    finally:
        server.close()
    tactile = driver("loop://", connect_timeout_s=0.2)  # a line that carries nothing
    with pytest.raises(TactileTimeoutError):
        tactile.connect()


def test_configuration_errors_are_one_line():
    with pytest.raises(ConfigError, match="bad item"):
        FaultPlan.parse("garbage@0")
    with pytest.raises(ConfigError, match="drop takes no argument"):
        FaultPlan.parse("drop@3:1")
    with pytest.raises(ConfigError, match="more than 80%"):
        TactileEmulator(ramp_source(), baud=9600)
    with pytest.raises(ConfigError, match="unknown tactile source"):
        make_tactile_emulator("twin")
    with pytest.raises(ConfigError):
        driver("ppsemu://", timeout_s=0)
    assert FaultPlan.parse("stall@5").at(5).arg is None
