"""The BH8-262 driver against the twin-backed emulator: Supervisory commands, ERR flags, RealTime,
the baud switch, bad ports; and fuzzing of the driver's reply handling over a real socket."""

import contextlib
import socket
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from twin.hardware.bh262.driver import BH262, HandTimeoutError, PortLostError, PortSettings
from twin.hardware.bh262.emulator import make_hand_emulator
from twin.hardware.bh262.hand import DEFAULT_REALTIME
from twin.hardware.bh262.protocol import ErrorFlag, HandCommandError, ProtocolError

from twin.interface.errors import DeviceError


@pytest.fixture(scope="module")
def empty_hand():
    """An emulated hand with nothing in it, on TCP, driven at 38400 baud after the switch."""
    with make_hand_emulator(None) as emulator:
        url = emulator.serve_tcp(0)
        bh = BH262(PortSettings(url=url, baud=9600, switch_baud=38400, baud_switch_wait_s=0.05))
        bh.open()
        yield bh, emulator
        bh.close()


def test_baud_switch_reaches_38400(empty_hand):
    bh, emulator = empty_hand
    assert bh.baud == 38400 and emulator.firmware.baud == 38400
    assert bh.pget("BAUD") == 384


def test_motion_commands_move_the_twin(empty_hand):
    bh, _ = empty_hand
    bh.initialize()
    assert max(bh.fget("", "P")) < 50
    bh.move("G", 5000)
    assert np.allclose(bh.fget("G", "P"), 5000, atol=100)
    bh.step_close("1", 1000)
    f1, f2, _ = bh.fget("G", "P")
    assert f1 - f2 == pytest.approx(1000, abs=100)
    bh.step_open("1", 1000)
    bh.close_fingers()
    closed = bh.fget("G", "P")
    assert min(closed) > 16_000  # empty hand: all the way to CT
    bh.open_fingers()
    assert max(bh.fget("G", "P")) < 100
    bh.terminate()


def test_properties_round_trip_and_errors_name_their_flags(empty_hand):
    bh, _ = empty_hand
    bh.fset("1", MCV=50)
    assert bh.fget("1", "MCV") == [50]
    assert bh.fget("1", "MCV", "MOV") == [50, 100]
    with pytest.raises(HandCommandError) as err:
        bh.fset("1", P=5)
    assert err.value.flags == ErrorFlag.WRITE_TO_READ_ONLY and "WRITE_TO_READ_ONLY" in str(err.value)
    with pytest.raises(HandCommandError) as err:
        bh.command("XYZZY")
    assert err.value.flags == ErrorFlag.UNKNOWN_COMMAND
    with pytest.raises(HandCommandError) as err:
        bh.fget("1", "NOPE")
    assert err.value.flags == ErrorFlag.UNKNOWN_PARAMETER
    with pytest.raises(HandCommandError) as err:
        bh.fset("1", MCV=5)  # below 16
    assert err.value.flags == ErrorFlag.INVALID_VALUE
    bh.command("FDEF")
    assert bh.fget("1", "MCV") == [100]


def test_realtime_loop_moves_and_reports(empty_hand):
    bh, _ = empty_hand
    bh.initialize()
    bh.enter_realtime(DEFAULT_REALTIME)
    start = bh.cycle()
    assert start.fields["LFAP"][:3] == [0, 0, 0] or max(start.fields["LFAP"][:3]) < 50
    assert all(100 <= s <= 140 for s in start.fields["LFS"][:3])  # no-load strain (hardware_facts §2)
    assert start.fields["LFS"][3] == 255  # the spread has no gauge
    t_end = time.monotonic() + 0.3
    while time.monotonic() < t_end:
        fb = bh.cycle({"LCV": [30, 30, 30, 0], "LCPG": [100] * 4})  # 3000 counts/s
    assert all(600 < p < 1000 for p in fb.fields["LFAP"][:3])  # 900 at full speed, less the ramp-up
    assert fb.fields["LFV"][:3] == [30, 30, 30]
    assert bh.cycle({"LCV": [0] * 4, "LCPG": [100] * 4}, feedback=False) is None
    bh.leave_realtime()
    assert bh.realtime is None
    assert len(bh.fget("", "P")) == 4


def test_reset_returns_to_9600_and_uninitialized():
    with make_hand_emulator(None) as emulator:
        bh = BH262(PortSettings(url=emulator.serve_tcp(0), switch_baud=38400, baud_switch_wait_s=0.05))
        bh.open()
        bh.initialize()
        bh.reset()
        assert bh.baud == 9600 and emulator.firmware.baud == 9600
        with pytest.raises(HandCommandError) as err:
            bh.close_fingers()
        assert err.value.flags == ErrorFlag.MOTOR_NOT_INITIALIZED
        bh.close()


def test_bh8emu_url_opens_an_in_process_emulator():
    bh = BH262(PortSettings(url="bh8emu://?object=none", switch_baud=None))
    bh.open()
    assert bh.pget("BAUD") == 96
    bh.close()


def test_bad_ports_fail_in_one_line():
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(DeviceError, match="cannot open the hand's port"):
        BH262(PortSettings(url=f"socket://127.0.0.1:{port}")).open()
    with pytest.raises(DeviceError, match="cannot open"):
        BH262(PortSettings(url="/dev/does-not-exist")).open()
    silent = BH262(PortSettings(url="loop://", timeout_s=0.1))  # echoes, never prompts
    with pytest.raises(HandTimeoutError, match="powered on"):
        silent.open()
    silent.close()


# --- fuzzing the driver's side of the wire ---------------------------------------------------

FUZZ = settings(max_examples=10_000, deadline=None)


class _Peer:
    """A TCP peer that answers whatever we put in its mouth, for feeding bytes to the driver."""

    def __init__(self) -> None:
        server = socket.create_server(("127.0.0.1", 0))
        self.bh = BH262(
            PortSettings(
                url=f"socket://127.0.0.1:{server.getsockname()[1]}", timeout_s=0.2, realtime_timeout_s=0.02
            )
        )
        self.bh._port = __import__("serial").serial_for_url(self.bh.settings.url, timeout=0.2)
        self.sock, _ = server.accept()
        server.close()
        self.sock.setblocking(False)

    def feed(self, data: bytes) -> None:
        with contextlib.suppress(BlockingIOError):
            while self.sock.recv(65536):
                pass
        self.bh._port.reset_input_buffer()
        self.sock.sendall(data)

    def close(self) -> None:
        self.bh._port.close()
        self.sock.close()


_peer: _Peer | None = None


def peer() -> _Peer:
    global _peer
    if _peer is None:
        _peer = _Peer()
    return _peer


@pytest.fixture(scope="module", autouse=True)
def _peer_closed():
    """The fuzzers share one peer (a connection per example would dominate their time): closed after."""
    global _peer
    yield
    if _peer is not None:
        _peer.close()
        _peer = None


@pytest.mark.slow
@FUZZ
@given(st.binary(max_size=120), st.sampled_from(["1FGET P", "HI", "PGET BAUD", "T"]))
def test_fuzz_supervisory_replies_only_declared_errors(raw, command):
    """Whatever comes back before the prompt, command() returns a reply or raises a DeviceError."""
    p = peer()
    p.feed(raw + b"=> ")
    with contextlib.suppress(DeviceError):
        p.bh.command(command)


@pytest.mark.slow
@FUZZ
@given(st.binary(min_size=DEFAULT_REALTIME.feedback_size, max_size=DEFAULT_REALTIME.feedback_size))
def test_fuzz_realtime_feedback_only_declared_errors(raw):
    """Any feedback-sized block decodes to four motors' fields or raises a ProtocolError."""
    p = peer()
    p.bh.realtime = DEFAULT_REALTIME
    p.feed(raw)
    try:
        fb = p.bh.cycle()
    except ProtocolError:
        return
    except HandTimeoutError:  # an error reply cut short by the prompt never coming
        return
    assert raw[:1] == b"*" and all(len(v) == 4 for v in fb.fields.values())


@pytest.mark.parametrize("order", ["motor", "property"])
def test_fget_order_is_an_option_both_sides_agree_on(order):
    from twin.hardware.bh262.protocol import WireOptions

    options = WireOptions(fget_order=order)
    with make_hand_emulator(None, options=options) as emulator:
        bh = BH262(PortSettings(url=emulator.serve_tcp(0), switch_baud=None, options=options))
        bh.open()
        bh.fset("2", MCV=40)
        raw = bh.fget("12", "MCV", "MOV")
        assert raw == ([100, 100, 40, 100] if order == "motor" else [100, 40, 100, 100])
        table = bh.fget_table("12", "MCV", "MOV")
        assert table == {(1, "MCV"): 100, (1, "MOV"): 100, (2, "MCV"): 40, (2, "MOV"): 100}
        bh.close()


def test_wire_options_refuse_unknown_choices():
    from twin.hardware.bh262.protocol import WireOptions

    for bad in ({"fget_order": "diagonal"}, {"velocity_unit_s": 0.5}, {"line_end": b"\n"}):
        with pytest.raises(ValueError):
            WireOptions(**bad)
    assert WireOptions(velocity_unit_s=409.6e-6 / 16).velocity_unit_s == pytest.approx(25.6e-6)


def test_a_session_leaves_the_hand_at_the_rate_the_next_one_expects():
    from twin.hardware.backend import WallClock
    from twin.hardware.bh262.hand import BH8SerialHand

    from twin.interface.hand_spec import HandConfig

    with make_hand_emulator(None) as emulator:
        port = PortSettings(url=emulator.serve_tcp(0), switch_baud=38400, baud_switch_wait_s=0.05)
        hand = BH8SerialHand(HandConfig(), port, WallClock())
        hand.connect()
        assert emulator.firmware.baud == 38400
        hand.disconnect()
        assert emulator.firmware.baud == 9600 and emulator.firmware.commands[-3:] == ["T", "PSET BAUD 96", ""]


def test_a_hand_left_at_the_fast_rate_is_found_there():
    with make_hand_emulator(None, baud=38400) as emulator:  # as a crashed session would leave it
        bh = BH262(PortSettings(url=emulator.serve_tcp(0), baud=9600, switch_baud=38400, timeout_s=0.2))
        bh.open()
        assert bh.baud == 38400 and bh.pget("BAUD") == 384
        bh.close()


def test_a_vanished_pty_is_a_port_lost_error_not_a_termios_error():
    """Once the far end of a pty closes, tcflush fails with termios.error (not an OSError): the driver
    reports the lost port like every other I/O failure, so a run's cleanup ends in one clear line."""
    emulator = make_hand_emulator(None)
    bh = BH262(PortSettings(url=emulator.serve_pty(), baud=9600))
    bh.open()
    try:
        emulator.close()  # the pty's master side goes away
        with pytest.raises(PortLostError, match="hand's port /dev/pts/"):
            bh.resync(0.1)
    finally:
        bh.close()
        emulator.close()


@pytest.mark.parametrize(
    ("switch_baud", "rate_hz", "advice", "never"),
    [
        (None, 30.0, "switch_baud = 38400", None),  # at 9600 the fix is the faster rate
        (38400, 200.0, "rate_hz at most 109", "38400 (the fastest"),  # already there: only a lower rate
    ],
)
def test_a_rate_the_wire_cannot_carry_is_refused_with_true_advice(switch_baud, rate_hz, advice, never):
    from twin.hardware.backend import WallClock
    from twin.hardware.bh262.hand import BH8SerialHand

    from twin.interface.errors import ConfigError
    from twin.interface.hand_spec import HandConfig

    port = PortSettings(url="/dev/never-opened", switch_baud=switch_baud)
    hand = BH8SerialHand(HandConfig(rate_hz=rate_hz), port, WallClock())
    with pytest.raises(ConfigError) as err:
        hand.connect()  # refused before the port is opened
    assert advice in str(err.value)
    assert never is None or never not in str(err.value)


def test_a_prompt_that_came_late_does_not_derail_the_next_command_or_loop():
    """On a busy machine a resync's prompt can arrive after the resync gave up on it: the next
    command (or LOOP) must read past it to its own answer instead of failing the recovery."""
    p = peer()
    p.bh.realtime = None
    p.feed(b"\n\r=> " + b"PGET BAUD\n\r384\n\r=> ")
    assert p.bh.pget("BAUD") == 384
    p.feed(b"=> => " + b"1234LOOP*")
    p.bh._loop(DEFAULT_REALTIME)
    assert p.bh.realtime == DEFAULT_REALTIME
    p.bh.realtime = None
    p.feed(b"=> " + b"1234LOOP\n\rERR 4\n\r=> ")  # an error after a stale prompt is still the error
    with pytest.raises(HandCommandError, match="4"):
        p.bh._loop(DEFAULT_REALTIME)
    assert p.bh.realtime is None


def test_a_host_that_stalls_between_commands_does_not_set_the_fingers_swinging():
    """The 262's RealTime mode takes velocities, and a velocity stays in force until the next control
    block: one that closes the set-point error within a 33 ms period, held through a 150 ms stall of
    the host, drives 4.5 times as far, past the target by 3.5 times the error, and each correction
    overshoots further (a loaded bridge's block swung its fingers by 1,500 counts this way). A host
    that has been stalling sends what closes the error within its longest recent gap instead, so the
    finger settles on its target however the stalls fall."""
    from twin.hardware.backend import WallClock
    from twin.hardware.bh262.hand import BH8SerialHand

    from twin.interface.devices import HandCommand
    from twin.interface.hand_spec import HandConfig

    with make_hand_emulator(None) as emulator:
        port = PortSettings(url=emulator.serve_tcp(0), switch_baud=38400, baud_switch_wait_s=0.05)
        hand = BH8SerialHand(HandConfig(), port, WallClock())
        hand.connect()
        try:
            start = hand.read().position_counts.astype(float)
            target = start + np.array([3000.0, 0.0, 0.0, 0.0])
            f1 = []
            for cycle in range(60):  # ~4 s: a burst of three cycles, then a 150 ms stall, as the bridge did
                f1.append(float(hand.read().position_counts[0]))
                hand.command(HandCommand(target, 12_000.0))
                time.sleep(0.15 if cycle % 3 == 2 else 0.01)
        finally:
            hand.disconnect()
    settled = np.array(f1[-15:]) - target[0]  # the last second
    assert np.max(np.abs(settled)) < 150, f"F1 off its target by {np.round(settled).astype(int).tolist()}"
