"""The BH8-262 emulator against a client written only from the protocol summary bh262_protocol.md.

Nothing here comes from `twin.hardware.bh262` (no driver, codec or emulator class): the emulator runs as a
separate process through the real CLI (`twin emulate hand`), and this file talks raw bytes to it with
pyserial. Expected bytes are the spec's own: echo, LF CR, result, LF CR, `=> ` (the spec's examples
write LF CR; the manual's "CRLF" is the (?) item, so the examples are what is asserted). Items the
spec marks (?) are asserted only where the reading is unambiguous; each such place says so.
"""

from __future__ import annotations

import re
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import serial

PROMPT = b"=> "
LE = b"\n\r"  # what the spec's examples send after the echo and after the result
CTRL_C = b"\x03"  # leaves RealTime mode
ERR_MOTOR_NOT_INITIALIZED = 4
ERR_UNKNOWN_COMMAND = 32
ERR_UNKNOWN_PARAMETER = 64
ERR_INVALID_VALUE = 128
ERR_WRITE_TO_READ_ONLY = 256
ERR_INVALID_REALTIME_HEADER = 2048
ERR_INVALID_MOTOR_PREFIX = 4096
ERR_ABORTED = 16384
BITS_PER_BYTE = 10  # 8N1: start bit, 8 data bits, stop bit
MOTION_TIMEOUT_S = 10.0  # C/O take about 2 s; the prompt comes only once the fingers stop
REPLY_TIMEOUT_S = 3.0
START_TIMEOUT_S = 60.0

_twin_script = Path(sys.executable).with_name("twin")
TWIN = [str(_twin_script)] if _twin_script.exists() else [sys.executable, "-m", "twin.cli"]


# --- the emulator process ------------------------------------------------------------------


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=10)
    if proc.stdout is not None:
        proc.stdout.close()


def _address(proc: subprocess.Popen) -> str:
    """The address on the emulator's "hand: ADDRESS  (...)" line."""
    watchdog = threading.Timer(START_TIMEOUT_S, proc.kill)  # a hung start must not hang the suite
    watchdog.start()
    lines: list[str] = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("hand:"):
                return line.split()[1]
    finally:
        watchdog.cancel()
    raise AssertionError(f"emulator gave no 'hand:' line: {lines}")


@pytest.fixture
def launch() -> Iterator[Callable[..., str]]:
    """Start `twin emulate hand OPTIONS...`; returns the address of its "hand:" line. Stopped at teardown."""
    procs: list[subprocess.Popen] = []

    def start(*options: str) -> str:
        proc = subprocess.Popen(
            [*TWIN, "emulate", "hand", *options], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        procs.append(proc)
        return _address(proc)

    yield start
    for proc in procs:
        _stop(proc)


def _open(address: str, baud: int) -> serial.Serial:
    port = serial.serial_for_url(address, baudrate=baud, timeout=REPLY_TIMEOUT_S)
    # Resynchronise as the clients do: a bare CR, then read up to the prompt.
    port.write(b"\r")
    assert read_until_prompt(port, REPLY_TIMEOUT_S) == PROMPT
    return port


@pytest.fixture
def hand(launch: Callable[..., str]) -> Iterator[serial.Serial]:
    """A freshly powered-up emulated hand (pty, no object, 9600 baud) and an open port to it."""
    port = _open(launch("--port", "pty", "--object", "none", "--baud", "9600"), 9600)
    yield port
    port.close()


@pytest.fixture(scope="module")
def _shared_hand() -> Iterator[serial.Serial]:
    """One emulated hand (pty, no object, 9600 baud), initialized with `HI`, for the tests that do not
    need a fresh power-up: starting a process per test would cost most of the time budget."""
    proc = subprocess.Popen(
        [*TWIN, "emulate", "hand", "--port", "pty", "--object", "none", "--baud", "9600"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        port = _open(_address(proc), 9600)
        try:
            assert command(port, "HI", MOTION_TIMEOUT_S) == b"HI" + LE + PROMPT
            yield port
        finally:
            port.close()
    finally:
        _stop(proc)


@pytest.fixture
def ready_hand(_shared_hand: serial.Serial) -> serial.Serial:
    """The shared, initialized hand, resynchronised: a CR (in RealTime mode, left behind by a failed
    test, it is an invalid header whose error reply ends in the prompt), then a CR that gives `=> `."""
    port = _shared_hand
    port.write(b"\r")
    read_until_prompt(port, REPLY_TIMEOUT_S)
    port.reset_input_buffer()
    port.write(b"\r")
    assert read_until_prompt(port, REPLY_TIMEOUT_S) == PROMPT
    return port


# --- a client from the spec -----------------------------------------------------------------


def read_until_prompt(port: serial.Serial, timeout: float) -> bytes:
    """Everything up to and including the prompt `=> `; fails if it does not come within `timeout`."""
    port.timeout = timeout
    data = port.read_until(PROMPT)
    if not data.endswith(PROMPT):
        raise AssertionError(f"no prompt within {timeout} s; got {data!r}")
    return data


def read_exactly(port: serial.Serial, n: int, timeout: float = REPLY_TIMEOUT_S) -> bytes:
    port.timeout = timeout
    data = port.read(n)
    assert len(data) == n, f"wanted {n} bytes within {timeout} s, got {data!r}"
    return data


def assert_quiet(port: serial.Serial, wait_s: float = 0.15) -> None:
    """Nothing more arrives (a reply had no trailing bytes)."""
    port.timeout = wait_s
    extra = port.read(256)
    assert extra == b"", f"unexpected extra bytes {extra!r}"


def command(port: serial.Serial, line: str, timeout: float = REPLY_TIMEOUT_S) -> bytes:
    """Send one supervisory command (CR-terminated); the raw reply up to the prompt."""
    port.write(line.encode("ascii") + b"\r")
    return read_until_prompt(port, timeout)


def values(port: serial.Serial, line: str, timeout: float = REPLY_TIMEOUT_S) -> list[int]:
    """A command with a result: `<echo>\\n\\r<int> <int>...\\n\\r=> ` -> the integers."""
    raw = command(port, line, timeout)
    m = re.fullmatch(re.escape(line.encode()) + rb"\n\r(-?\d+(?: -?\d+)*)\n\r=> ", raw)
    assert m, f"{line!r}: malformed reply {raw!r}"
    return [int(v) for v in m.group(1).split()]


def error_reply(line: str, code: int) -> bytes:
    return line.encode() + LE + f"ERR {code}".encode() + LE + PROMPT


def fingers(port: serial.Serial) -> list[int]:
    """F1 F2 F3 from `FGET P` (order 1, 2, 3, 4 = spread)."""
    positions = values(port, "FGET P")
    assert len(positions) == 4
    return positions[:3]


def enter_loop(port: serial.Serial, prefix: str) -> None:
    """`<prefix>LOOP\\r` -> the echo and a single `*`, no LF CR."""
    echo = f"{prefix}LOOP".encode()
    port.write(echo + b"\r")
    assert read_exactly(port, len(echo) + 1) == echo + b"*"


def leave_loop(port: serial.Serial) -> bytes:
    port.write(CTRL_C)
    return read_until_prompt(port, REPLY_TIMEOUT_S)


# RealTime layout used below: every motor 1-4 with LCV+LCPG control and LFV+LFS+LFAP feedback.
RT_FLAGS = "LCV 1 LCPG 1 LCT 0 LFV 1 LFS 1 LFAP 1 LFDP 0 LFBP 0 LFAIN 0 LCVC 1 LFVC 1"
RT_CONTROL = ">" + "bB" * 4  # per motor: LCV int8, LCPG uint8
RT_FEEDBACK = ">" + "bBH" * 4  # per motor: LFV int8, LFS uint8, LFAP uint16 big-endian


def setup_realtime(port: serial.Serial, prefix: str, flags: str) -> None:
    line = f"{prefix}FSET {flags}"
    assert command(port, line) == line.encode() + LE + PROMPT
    assert command(port, "PSET LFT 0") == b"PSET LFT 0" + LE + PROMPT


def control(lcv: tuple[int, int, int, int], gain: int = 200) -> bytes:
    return struct.pack(RT_CONTROL, *(x for v in lcv for x in (v, gain)))


def feedback(port: serial.Serial, header: bytes, data: bytes = b"") -> list[tuple[int, int, int]]:
    """One `C`/`A` block -> per motor (LFV, LFS, LFAP)."""
    port.write(header + data)
    block = read_exactly(port, 1 + struct.calcsize(RT_FEEDBACK))
    assert block[:1] == b"*", block
    flat = struct.unpack(RT_FEEDBACK, block[1:])
    return [flat[i : i + 3] for i in range(0, 12, 3)]


# --- 1, 2: supervisory framing -----------------------------------------------------------------


def test_bare_cr_returns_just_the_prompt(ready_hand: serial.Serial):
    ready_hand.write(b"\r")
    assert read_until_prompt(ready_hand, REPLY_TIMEOUT_S) == PROMPT
    assert_quiet(ready_hand)


def test_fget_one_motor_is_echo_lfcr_result_lfcr_prompt(ready_hand: serial.Serial):
    raw = command(ready_hand, "1FGET P")
    assert re.fullmatch(rb"1FGET P\n\r\d+\n\r=> ", raw), raw
    assert_quiet(ready_hand)


def test_a_command_sent_in_pieces_is_answered_once_the_cr_comes(ready_hand: serial.Serial):
    # When the echo comes is not specified (as the characters arrive, or with the line): only the whole.
    ready_hand.write(b"1FGE")
    time.sleep(0.2)
    ready_hand.write(b"T P\r")
    assert re.fullmatch(rb"1FGET P\n\r\d+\n\r=> ", read_until_prompt(ready_hand, REPLY_TIMEOUT_S))


def test_echo_repeats_every_character_but_the_cr(ready_hand: serial.Serial):
    # "The hand echoes the command characters (not the CR)": spaces included.
    ready_hand.write(b" 1FGET P  \r")
    raw = read_until_prompt(ready_hand, REPLY_TIMEOUT_S)
    assert re.fullmatch(rb" 1FGET P  \n\r\d+\n\r=> ", raw), raw


def test_tcp_link_frames_like_the_pty(launch: Callable[..., str]):
    port = _open(launch("--port", "tcp:0", "--object", "none"), 9600)
    try:
        port.write(b"\r")
        assert read_until_prompt(port, REPLY_TIMEOUT_S) == PROMPT
        assert re.fullmatch(rb"1FGET P\n\r\d+\n\r=> ", command(port, "1FGET P"))
        assert command(port, "XYZ") == error_reply("XYZ", ERR_UNKNOWN_COMMAND)
    finally:
        port.close()


def test_fget_gives_one_value_per_motor_in_order_1234(ready_hand: serial.Serial):
    targets = {"1": 2000, "2": 3000, "3": 4000, "S": 1000}  # distinct, so that the order shows
    for motor, target in targets.items():
        line = f"{motor}M {target}"
        assert command(ready_hand, line, MOTION_TIMEOUT_S) == line.encode() + LE + PROMPT
    positions = values(ready_hand, "FGET P")  # F1 F2 F3 S
    assert positions == pytest.approx(list(targets.values()), abs=300)
    near = {"abs": 20}  # the readings may wobble by a count or two between commands
    assert values(ready_hand, "123FGET P") == pytest.approx(positions[:3], **near)
    assert values(ready_hand, "GSFGET P") == pytest.approx(positions, **near)
    assert values(ready_hand, "1234FGET P") == pytest.approx(positions, **near)
    assert values(ready_hand, "SFGET P") == pytest.approx([positions[3]], **near)
    assert values(ready_hand, "4FGET P") == pytest.approx([positions[3]], **near)
    assert values(ready_hand, "2FGET P") == pytest.approx([positions[1]], **near)
    assert values(ready_hand, "31FGET P") == pytest.approx([positions[0], positions[2]], **near)


def test_fget_one_motor_several_properties_gives_one_value_per_property(ready_hand: serial.Serial):
    mcv, mov, position = values(ready_hand, "1FGET MCV MOV P")
    assert (mcv, mov) == (100, 100)  # the documented finger defaults
    assert abs(position - values(ready_hand, "1FGET P")[0]) <= 20
    assert values(ready_hand, "4FGET MCV MOV") == [60, 60]  # the spread's


def test_fset_sets_only_the_prefixed_motors(ready_hand: serial.Serial):
    before = values(ready_hand, "13FGET DP")
    assert 4321 not in before
    assert command(ready_hand, "2FSET DP 4321") == b"2FSET DP 4321" + LE + PROMPT
    assert values(ready_hand, "123FGET DP") == [before[0], 4321, before[1]]


def test_command_without_result_is_echo_lfcr_prompt(ready_hand: serial.Serial):
    assert command(ready_hand, "T") == b"T" + LE + PROMPT
    assert_quiet(ready_hand)


def test_no_load_strain_is_in_the_adjusted_range(ready_hand: serial.Serial):
    # "the no-load value is adjusted to 100-140" (no object in the hand, fingers open).
    assert command(ready_hand, "GM 1000", MOTION_TIMEOUT_S) == b"GM 1000" + LE + PROMPT
    assert all(100 <= sg <= 140 for sg in values(ready_hand, "123FGET SG"))


# --- 3: errors -------------------------------------------------------------------------------


def test_unknown_command_is_err_32(ready_hand: serial.Serial):
    assert command(ready_hand, "XYZ") == error_reply("XYZ", ERR_UNKNOWN_COMMAND)


def test_motion_before_hi_is_err_4_and_nothing_moves(hand: serial.Serial):
    before = fingers(hand)
    assert command(hand, "C") == error_reply("C", ERR_MOTOR_NOT_INITIALIZED)
    assert command(hand, "GM 5000") == error_reply("GM 5000", ERR_MOTOR_NOT_INITIALIZED)
    assert command(hand, "GIC 1000") == error_reply("GIC 1000", ERR_MOTOR_NOT_INITIALIZED)
    time.sleep(0.3)
    assert all(abs(a - b) < 50 for a, b in zip(fingers(hand), before, strict=True))
    # ... and after HI the same motion is accepted.
    assert command(hand, "HI", MOTION_TIMEOUT_S) == b"HI" + LE + PROMPT
    assert command(hand, "GM 5000", MOTION_TIMEOUT_S) == b"GM 5000" + LE + PROMPT


def test_unknown_property_in_fget_is_err_64(ready_hand: serial.Serial):
    assert command(ready_hand, "1FGET XYZ") == error_reply("1FGET XYZ", ERR_UNKNOWN_PARAMETER)


def test_writing_a_read_only_property_is_err_256(ready_hand: serial.Serial):
    assert command(ready_hand, "1FSET P 5") == error_reply("1FSET P 5", ERR_WRITE_TO_READ_ONLY)


def test_out_of_range_value_is_err_128(ready_hand: serial.Serial):
    # MCV / MOV: 16-4080
    assert command(ready_hand, "1FSET MCV 5000") == error_reply("1FSET MCV 5000", ERR_INVALID_VALUE)
    assert values(ready_hand, "1FGET MCV") == [100]


def test_invalid_motor_prefix_is_err_4096(ready_hand: serial.Serial):
    # On an initialized hand, so that "motor not initialized" (4) cannot be summed in.
    assert command(ready_hand, "9C") == error_reply("9C", ERR_INVALID_MOTOR_PREFIX)
    assert command(ready_hand, "9FGET P") == error_reply("9FGET P", ERR_INVALID_MOTOR_PREFIX)


# --- 4: motion ---------------------------------------------------------------------------------


def test_close_then_open(ready_hand: serial.Serial):
    assert command(ready_hand, "C", MOTION_TIMEOUT_S) == b"C" + LE + PROMPT
    closed = fingers(ready_hand)
    assert all(p > 5000 for p in closed), closed
    # The prompt comes only once the motion has finished: the fingers no longer move.
    time.sleep(0.3)
    assert all(abs(a - b) <= 50 for a, b in zip(fingers(ready_hand), closed, strict=True))
    assert command(ready_hand, "O", MOTION_TIMEOUT_S) == b"O" + LE + PROMPT
    opened = fingers(ready_hand)
    assert all(p < 300 for p in opened), opened


def test_move_to_a_position(ready_hand: serial.Serial):
    # `GM`: the fingers only (5000 is beyond the spread's 0-3150 range); the spread stays put.
    spread_before = values(ready_hand, "SFGET P")[0]
    assert command(ready_hand, "GM 5000", MOTION_TIMEOUT_S) == b"GM 5000" + LE + PROMPT
    *moved, spread = values(ready_hand, "FGET P")
    assert all(abs(p - 5000) < 300 for p in moved), moved
    assert abs(spread - spread_before) < 50


def test_step_close_and_open(ready_hand: serial.Serial):
    assert command(ready_hand, "GM 5000", MOTION_TIMEOUT_S) == b"GM 5000" + LE + PROMPT
    start = fingers(ready_hand)
    assert command(ready_hand, "GIC 1000", MOTION_TIMEOUT_S) == b"GIC 1000" + LE + PROMPT
    closed = fingers(ready_hand)
    assert all(abs(b - a - 1000) < 150 for a, b in zip(start, closed, strict=True)), (start, closed)
    assert command(ready_hand, "GIO 1000", MOTION_TIMEOUT_S) == b"GIO 1000" + LE + PROMPT
    opened = fingers(ready_hand)
    assert all(abs(a - b - 1000) < 150 for a, b in zip(closed, opened, strict=True)), (closed, opened)


def test_move_and_step_without_argument_use_dp_and_ds(ready_hand: serial.Serial):
    assert command(ready_hand, "GM", MOTION_TIMEOUT_S) == b"GM" + LE + PROMPT
    dp = values(ready_hand, "123FGET DP")
    positions = fingers(ready_hand)
    assert all(abs(p - d) < 300 for p, d in zip(positions, dp, strict=True)), (positions, dp)
    ds = values(ready_hand, "123FGET DS")
    assert command(ready_hand, "GIO", MOTION_TIMEOUT_S) == b"GIO" + LE + PROMPT
    stepped = fingers(ready_hand)
    assert all(abs(a - b - d) < 150 for a, b, d in zip(positions, stepped, ds, strict=True)), (positions, ds)


def test_close_and_open_go_to_the_ct_and_ot_targets(ready_hand: serial.Serial):
    ct, ot = values(ready_hand, "1FGET CT OT")
    try:
        assert command(ready_hand, "1FSET CT 6000 OT 2000") == b"1FSET CT 6000 OT 2000" + LE + PROMPT
        assert command(ready_hand, "1C", MOTION_TIMEOUT_S) == b"1C" + LE + PROMPT
        assert abs(values(ready_hand, "1FGET P")[0] - 6000) < 300
        assert command(ready_hand, "1O", MOTION_TIMEOUT_S) == b"1O" + LE + PROMPT
        assert abs(values(ready_hand, "1FGET P")[0] - 2000) < 300
    finally:
        command(ready_hand, f"1FSET CT {ct} OT {ot}")


def test_ctrl_c_aborts_a_motion_with_err_16384(ready_hand: serial.Serial):
    # Only the error table speaks of it ("16384 aborted by Ctrl-C"); asserted: the motion's reply is
    # that error, and finger 1 stops short of its target.
    assert command(ready_hand, "1M 0", MOTION_TIMEOUT_S) == b"1M 0" + LE + PROMPT
    ready_hand.write(b"1M 6000\r")  # about 0.6 s at the default MCV
    time.sleep(0.15)
    ready_hand.write(CTRL_C)
    try:
        assert read_until_prompt(ready_hand, MOTION_TIMEOUT_S) == error_reply("1M 6000", ERR_ABORTED)
        assert values(ready_hand, "1FGET P")[0] < 5000
    finally:
        ready_hand.write(b"\r")  # whatever happened, back to a prompt and finger 1 open
        read_until_prompt(ready_hand, MOTION_TIMEOUT_S)
        command(ready_hand, "1M 0", MOTION_TIMEOUT_S)


def test_hi_and_home_open_the_fingers(ready_hand: serial.Serial):
    assert command(ready_hand, "GM 2000", MOTION_TIMEOUT_S) == b"GM 2000" + LE + PROMPT
    assert command(ready_hand, "HI", MOTION_TIMEOUT_S) == b"HI" + LE + PROMPT
    assert all(p < 300 for p in fingers(ready_hand))
    assert command(ready_hand, "GM 2000", MOTION_TIMEOUT_S) == b"GM 2000" + LE + PROMPT
    assert command(ready_hand, "GHOME", MOTION_TIMEOUT_S) == b"GHOME" + LE + PROMPT
    assert all(p < 300 for p in fingers(ready_hand))


# --- 5, 6: RealTime ----------------------------------------------------------------------------


def test_loop_echoes_then_a_single_star(ready_hand: serial.Serial):
    setup_realtime(ready_hand, "1234", RT_FLAGS)
    enter_loop(ready_hand, "1234")
    assert_quiet(ready_hand)  # no LF CR, no prompt after the '*'
    leave_loop(ready_hand)


def test_realtime_block_sizes_for_each_header(ready_hand: serial.Serial):
    assert command(ready_hand, "GM 3000", MOTION_TIMEOUT_S) == b"GM 3000" + LE + PROMPT
    positions = values(ready_hand, "FGET P")
    setup_realtime(ready_hand, "1234", RT_FLAGS)
    enter_loop(ready_hand, "1234")
    hold = control((0, 0, 0, 0))
    assert len(hold) == 8
    # C + control -> '*' + 16 bytes of feedback; LFAP is the position FGET P reported.
    motors = feedback(ready_hand, b"C", hold)
    assert all(abs(lfap - p) < 100 for (_, _, lfap), p in zip(motors, positions, strict=True)), motors
    assert all(100 <= lfs <= 140 for _, lfs, _ in motors[:3]), motors  # no-load strain
    assert_quiet(ready_hand)
    # A: feedback without control.
    assert len(feedback(ready_hand, b"A")) == 4
    assert_quiet(ready_hand)
    # c + control -> '*' only; a -> '*' only. Control bytes are not echoed.
    ready_hand.write(b"c" + hold)
    assert read_exactly(ready_hand, 1) == b"*"
    assert_quiet(ready_hand)
    ready_hand.write(b"a")
    assert read_exactly(ready_hand, 1) == b"*"
    assert_quiet(ready_hand)
    leave_loop(ready_hand)


def test_closing_velocity_makes_lfap_grow(ready_hand: serial.Serial):
    assert command(ready_hand, "GM 2000", MOTION_TIMEOUT_S) == b"GM 2000" + LE + PROMPT
    setup_realtime(ready_hand, "1234", RT_FLAGS)
    enter_loop(ready_hand, "1234")
    start = [lfap for _, _, lfap in feedback(ready_hand, b"A")]
    close = control((40, 40, 40, 0))  # fingers close, the spread holds
    deadline = time.monotonic() + 3.0
    peak_velocity = [0, 0, 0]
    while True:
        motors = feedback(ready_hand, b"C", close)
        peak_velocity = [max(v, lfv) for v, (lfv, _, _) in zip(peak_velocity, motors, strict=False)]
        grown = [lfap - s for (_, _, lfap), s in zip(motors, start, strict=True)]
        if all(g > 1000 for g in grown[:3]) or time.monotonic() > deadline:
            break
    feedback(ready_hand, b"C", control((0, 0, 0, 0)))
    leave_loop(ready_hand)
    assert all(g > 1000 for g in grown[:3]), grown
    assert abs(grown[3]) < 50, grown  # LCV 0 on the spread
    assert all(v > 0 for v in peak_velocity), peak_velocity  # LFV: closing is positive


def test_lfdp_deltas_add_up_to_the_lfap_change(ready_hand: serial.Serial):
    # LFDPD 0: an overflow beyond +-127 is carried to the next cycle, so once the fingers stop the
    # accumulated deltas (x LFDPC) catch up with the absolute positions.
    assert command(ready_hand, "GM 2000", MOTION_TIMEOUT_S) == b"GM 2000" + LE + PROMPT
    flags = "LCV 1 LCPG 1 LCT 0 LFV 0 LFS 0 LFAP 1 LFDP 1 LFBP 0 LFAIN 0 LCVC 1 LFDPC 1"
    setup_realtime(ready_hand, "123", flags)
    assert command(ready_hand, "PSET LFDPD 0") == b"PSET LFDPD 0" + LE + PROMPT
    enter_loop(ready_hand, "123")
    layout = ">" + "Hb" * 3  # per motor: LFAP uint16, LFDP int8

    def cycle(lcv: int) -> tuple[list[int], list[int]]:
        ready_hand.write(b"C" + struct.pack(">" + "bB" * 3, lcv, 200, lcv, 200, lcv, 200))
        block = read_exactly(ready_hand, 1 + struct.calcsize(layout))
        assert block[:1] == b"*"
        flat = struct.unpack(layout, block[1:])
        return list(flat[0::2]), list(flat[1::2])

    start, _ = cycle(0)
    total = [0, 0, 0]
    deadline = time.monotonic() + 0.6
    while time.monotonic() < deadline:  # closing at up to 127 counts per 10 ms
        _, deltas = cycle(127)
        total = [t + d for t, d in zip(total, deltas, strict=True)]
    saturated = False
    for _ in range(200):  # stopped: the carried remainder drains
        lfap, deltas = cycle(0)
        saturated |= any(abs(d) == 127 for d in deltas)
        total = [t + d for t, d in zip(total, deltas, strict=True)]
        if all(d == 0 for d in deltas):
            break
    leave_loop(ready_hand)
    moved = [b - a for a, b in zip(start, lfap, strict=True)]
    assert all(m > 500 for m in moved), moved
    # >= 127 counts per 10 ms in either velocity unit, and a cycle takes >= 17 bytes x 1.04 ms at
    # 9600 baud: the deltas must have been clipped, so the carry was exercised.
    assert saturated
    assert all(abs(t - m) <= 2 for t, m in zip(total, moved, strict=True)), (total, moved)


def test_loop_with_lct_and_lcv_is_an_error_reply(ready_hand: serial.Serial):
    # "LCT cannot be combined with LCV or LCPG"; "anything else than `*` is an error reply ending in
    # `=> `" (the code is not given).
    setup_realtime(ready_hand, "1234", RT_FLAGS.replace("LCT 0", "LCT 1"))
    try:
        ready_hand.write(b"1234LOOP\r")
        raw = read_until_prompt(ready_hand, REPLY_TIMEOUT_S)
        assert re.fullmatch(rb"1234LOOP\n\rERR \d+\n\r=> ", raw), raw
        assert re.fullmatch(rb"1FGET P\n\r\d+\n\r=> ", command(ready_hand, "1FGET P"))
    finally:
        command(ready_hand, "1234FSET LCT 0")


def test_lft_appends_the_temperature(ready_hand: serial.Serial):
    # 1 byte (firmware 4.4) or 2 (4.3x): the spec marks the size (?), so either is accepted.
    setup_realtime(ready_hand, "1234", RT_FLAGS)
    assert command(ready_hand, "PSET LFT 1") == b"PSET LFT 1" + LE + PROMPT
    enter_loop(ready_hand, "1234")
    ready_hand.write(b"A")
    block = read_exactly(ready_hand, 1 + 16 + 1)
    ready_hand.timeout = 0.15
    block += ready_hand.read(8)  # a second temperature byte, if any
    leave_loop(ready_hand)
    assert command(ready_hand, "PSET LFT 0") == b"PSET LFT 0" + LE + PROMPT
    assert block[:1] == b"*"
    assert len(block) in (18, 19), block


def test_ctrl_c_leaves_realtime_and_supervisory_commands_work(ready_hand: serial.Serial):
    setup_realtime(ready_hand, "1234", RT_FLAGS)
    enter_loop(ready_hand, "1234")
    feedback(ready_hand, b"A")
    assert leave_loop(ready_hand).endswith(PROMPT)
    assert re.fullmatch(rb"1FGET P\n\r\d+\n\r=> ", command(ready_hand, "1FGET P"))


def test_spec_example_block_sizes(ready_hand: serial.Serial):
    # `123LOOP` with LCV+LCPG and LFS+LFAP -> C + 6 bytes out, '*' + 9 bytes back.
    flags = "LCV 1 LCPG 1 LCT 0 LFV 0 LFS 1 LFAP 1 LFDP 0 LFBP 0 LFAIN 0 LCVC 1"
    setup_realtime(ready_hand, "123", flags)
    enter_loop(ready_hand, "123")
    ready_hand.write(b"C" + struct.pack(">" + "bB" * 3, 0, 100, 0, 100, 0, 100))
    assert read_exactly(ready_hand, 10)[:1] == b"*"
    assert_quiet(ready_hand)
    leave_loop(ready_hand)
    # `1234LOOP` with LFV+LFAP -> '*' + 12 bytes back.
    setup_realtime(ready_hand, "1234", "LCV 0 LCPG 0 LCT 0 LFV 1 LFS 0 LFAP 1 LFDP 0 LFBP 0 LFAIN 0")
    enter_loop(ready_hand, "1234")
    ready_hand.write(b"A")
    assert read_exactly(ready_hand, 13)[:1] == b"*"
    assert_quiet(ready_hand)
    leave_loop(ready_hand)


def test_invalid_realtime_header_is_err_2048(ready_hand: serial.Serial):
    setup_realtime(ready_hand, "1234", RT_FLAGS)
    enter_loop(ready_hand, "1234")
    ready_hand.write(b"Z")
    expected = LE + f"ERR {ERR_INVALID_REALTIME_HEADER}".encode() + LE + PROMPT
    assert read_until_prompt(ready_hand, REPLY_TIMEOUT_S) == expected
    assert_quiet(ready_hand)


def test_after_a_realtime_error_the_hand_is_in_supervisory_mode(ready_hand: serial.Serial):
    # The spec marks this (?); the error reply ends in the supervisory prompt and the clients assume
    # Supervisory mode, so that is the reading asserted.
    setup_realtime(ready_hand, "1234", RT_FLAGS)
    enter_loop(ready_hand, "1234")
    ready_hand.write(b"Z")
    read_until_prompt(ready_hand, REPLY_TIMEOUT_S)
    assert re.fullmatch(rb"1FGET P\n\r\d+\n\r=> ", command(ready_hand, "1FGET P"))


# --- 7: baud rate ------------------------------------------------------------------------------


def switch_to_38400(port: serial.Serial) -> None:
    """`PSET BAUD 384` as the spec's host does it: echo at the old rate, switch, wait, CR, prompt."""
    port.write(b"PSET BAUD 384\r")
    assert read_exactly(port, len(b"PSET BAUD 384")) == b"PSET BAUD 384"
    port.baudrate = 38400
    time.sleep(1.0)
    # What the hand sends between the echo and the CR is not specified (on a wire it would be noise
    # at the wrong rate), so it is discarded, as a host would.
    port.reset_input_buffer()
    port.write(b"\r")
    assert read_until_prompt(port, REPLY_TIMEOUT_S) == PROMPT


def test_pset_baud_384_switches_after_the_echo(hand: serial.Serial):
    switch_to_38400(hand)
    assert values(hand, "PGET BAUD") == [384]
    assert len(values(hand, "FGET P")) == 4


def test_reset_returns_to_9600(hand: serial.Serial):
    switch_to_38400(hand)
    raw = command(hand, "RESET")
    assert b"BarrettHand Firmware" in raw
    hand.baudrate = 9600
    time.sleep(0.2)
    hand.reset_input_buffer()
    hand.write(b"\r")
    assert read_until_prompt(hand, REPLY_TIMEOUT_S) == PROMPT
    assert values(hand, "PGET BAUD") == [96]


def test_reset_keeps_a_rate_saved_with_psave(hand: serial.Serial):
    switch_to_38400(hand)
    assert command(hand, "PSAVE") == b"PSAVE" + LE + PROMPT
    raw = command(hand, "RESET")
    assert b"BarrettHand Firmware" in raw
    hand.write(b"\r")
    assert read_until_prompt(hand, REPLY_TIMEOUT_S) == PROMPT
    assert values(hand, "PGET BAUD") == [384]


def _reply_bytes_and_time(port: serial.Serial, at_least: int) -> tuple[int, float]:
    total = 0
    t0 = time.monotonic()
    while total < at_least:
        total += len(command(port, "1FGET P"))
    return total, time.monotonic() - t0


def test_replies_are_paced_at_9600_baud(hand: serial.Serial):
    # A lower bound only: N reply bytes at R baud cannot arrive faster than N * 10 / R seconds.
    n, elapsed = _reply_bytes_and_time(hand, 150)
    assert elapsed >= 0.9 * n * BITS_PER_BYTE / 9600, (n, elapsed)


def test_powered_up_at_38400_it_answers_and_paces_at_38400(launch: Callable[..., str]):
    port = _open(launch("--port", "tcp:0", "--object", "none", "--baud", "38400"), 38400)
    try:
        assert values(port, "PGET BAUD") == [384]
        n, elapsed = _reply_bytes_and_time(port, 150)
        assert elapsed >= 0.9 * n * BITS_PER_BYTE / 38400, (n, elapsed)
    finally:
        port.close()


# --- 8, 9: RESET, lowercase --------------------------------------------------------------------


def test_reset_prints_the_banner_and_uninitializes(hand: serial.Serial):
    assert command(hand, "HI", MOTION_TIMEOUT_S) == b"HI" + LE + PROMPT
    assert command(hand, "GM 2000", MOTION_TIMEOUT_S) == b"GM 2000" + LE + PROMPT
    raw = command(hand, "RESET", MOTION_TIMEOUT_S)
    assert raw.startswith(b"RESET"), raw
    assert b"BarrettHand Firmware" in raw, raw
    assert_quiet(hand)  # one prompt only
    assert command(hand, "C") == error_reply("C", ERR_MOTOR_NOT_INITIALIZED)


def test_lowercase_commands_are_accepted(ready_hand: serial.Serial):
    # (?) in the spec: "seem accepted". The echo repeats the characters as sent.
    assert re.fullmatch(rb"1fget p\n\r\d+\n\r=> ", command(ready_hand, "1fget p"))
    assert command(ready_hand, "gm 3000", MOTION_TIMEOUT_S) == b"gm 3000" + LE + PROMPT
    assert all(abs(p - 3000) < 300 for p in fingers(ready_hand))
    assert command(ready_hand, "go", MOTION_TIMEOUT_S) == b"go" + LE + PROMPT
    assert all(p < 300 for p in fingers(ready_hand))


# --- the emulator's own arguments and its clients ----------------------------------------------


def test_an_unusable_fault_spec_is_refused_before_serving():
    """`late@31:nan` once passed and killed the serving thread at reply 31 while the process went on."""
    proc = subprocess.run(
        [*TWIN, "emulate", "hand", "--faults", "late@31:nan", "--duration", "30"],
        capture_output=True,
        text=True,
        timeout=START_TIMEOUT_S,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""  # no "hand:" line, no "ready"
    assert proc.stderr.startswith("twin: error: --faults: ") and proc.stderr.count("\n") == 1


def test_a_second_tcp_client_is_told_busy_and_closed(launch: Callable[..., str]):
    address = launch("--port", "tcp:0", "--object", "none")
    first = _open(address, 9600)
    try:
        second = serial.serial_for_url(address, baudrate=9600, timeout=REPLY_TIMEOUT_S)
        try:
            assert b"busy" in second.read_until(b"connected to this emulator")
        finally:
            second.close()
        first.write(b"\r")  # the first client still has the hand
        assert read_until_prompt(first, REPLY_TIMEOUT_S) == PROMPT
    finally:
        first.close()
