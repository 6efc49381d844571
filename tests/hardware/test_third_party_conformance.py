"""The emulator against the byte sequences of two BH8-262 clients nobody here wrote, replayed on a pty.

The sequences and what each client's parser needs are facts read from their public sources, written
here as bytes (no code of theirs is copied; see tools/third_party_clients/ for building and running
the clients themselves):
  - Barrett's BHand API 4.4.3 (`BHandSerialDriver.cpp`): a bare CR, then `RESET` and a search of the
    reply for "BarrettHand Firmware\\n"; `HI`; supervisory commands whose reply it reads up to `=> `
    and calls an error when it starts with "ERR"; RTSetFlags' `FSET`/`PSET` lines; RTStart's
    `FGET` of the nine flags per motor and `PGET LFT`, then `1234LOOP` answered by its echo and
    exactly `*`; `C` blocks answered by `*` and the feedback bytes; an error reply is found by
    "\\n\\rERR " and "\\n\\r=> "; RTAbort sends 0x03 and reads up to `=> `.
  - dmiller12/libgripper (`barrett_hand_driver.cpp`, `barrett_hand.cpp`): on connect 0x03 and a read
    up to `=> `; `1234FGET S` (HI only when a status is not 0); the echo compared byte for byte; replies
    read up to "\\n\\r=> "; "\\n\\rERR " is an error; `SFSET FPG 5 FIP 1 FDZ 100`; its RealTime flags
    with `LCVC 0` on the spread; `1234LOOP` then one byte `*`; `A` and `C` blocks of fixed reply size.
The manual's defaults are the BH8-series manual's (firmware 4.3x, §5.3).
"""

from __future__ import annotations

import os
import re
import select
import struct
import termios
import threading
import time
import tty
from collections.abc import Iterator

import pytest
from twin.hardware.bh262.emulator import HandEmulator, make_hand_emulator

PROMPT = b"=> "
LE = b"\n\r"
GUARD_S = 10.0
"""A hang guard, never a timing assertion."""
MOTION_GUARD_S = 20.0


class RawClient:
    """os.read/os.write on the emulator's pty, nothing of ours in between."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        termios.tcflush(self.fd, termios.TCIOFLUSH)

    def close(self) -> None:
        os.close(self.fd)

    def write(self, data: bytes) -> None:
        os.write(self.fd, data)

    def read_exactly(self, n: int, guard_s: float = GUARD_S) -> bytes:
        data = b""
        deadline = time.monotonic() + guard_s
        while len(data) < n:
            left = deadline - time.monotonic()
            assert left > 0 and select.select([self.fd], [], [], left)[0], f"hang: {data!r}, wanted {n}"
            data += os.read(self.fd, n - len(data))
        return data

    def read_until(self, end: bytes, guard_s: float = GUARD_S) -> bytes:
        data = b""
        deadline = time.monotonic() + guard_s
        while not data.endswith(end):
            left = deadline - time.monotonic()
            assert left > 0 and select.select([self.fd], [], [], left)[0], f"hang: no {end!r} in {data!r}"
            data += os.read(self.fd, 1)
        return data

    def barrett(self, line: str, guard_s: float = GUARD_S) -> str:
        """Barrett's HandleSupervisoryCall: write, drop the echo (all but the CR), read to `=> `, trim
        white space; returns the response, which must not start with "ERR"."""
        self.write(line.encode() + b"\r")
        self.read_exactly(len(line), guard_s)
        response = self.read_until(PROMPT, guard_s)[: -len(PROMPT)].decode().strip()
        assert not response.startswith("ERR"), (line, response)
        return response

    def libgripper(self, line: str, guard_s: float = 15.0) -> str:
        """libgripper's sendAsynchronousCommand: the echo must equal the command; the reply must end in
        "\\n\\r=> " and hold no "\\n\\rERR "; returns it without the marker."""
        self.write(line.encode() + b"\r")
        assert self.read_exactly(len(line), guard_s) == line.encode()
        reply = self.read_until(LE + PROMPT, guard_s)
        assert LE + b"ERR " not in reply, (line, reply)
        return reply[: -len(LE + PROMPT)].decode()


@pytest.fixture(scope="module")
def emulator() -> Iterator[HandEmulator]:
    emu = make_hand_emulator(None, baud=38400)
    emu.serve_pty()
    yield emu
    emu.close()
    assert emu.failed() is None


@pytest.fixture
def client(emulator: HandEmulator) -> Iterator[RawClient]:
    """A client on the shared hand, which is reset first (as at power-up: uninitialized, defaults)."""
    c = RawClient(emulator.address)
    c.write(b"\x03\r")
    c.read_until(PROMPT)
    time.sleep(0.05)
    termios.tcflush(c.fd, termios.TCIFLUSH)
    c.write(b"RESET\r")
    c.read_until(PROMPT)
    yield c
    c.close()


def ints(text: str) -> list[int]:
    return [int(v) for v in text.split()]


# --- Barrett's BHand API 4.4.3 ---------------------------------------------------------------------


def test_barrett_init_software_finds_the_banner_and_version(client: RawClient):
    client.write(b"\r")
    assert client.read_until(PROMPT) == PROMPT
    client.write(b"RESET\r")
    client.read_exactly(len("RESET"))
    response = client.read_until(PROMPT).lstrip()  # the API drops leading white space
    assert b"BarrettHand Firmware\n" in response  # searchstrn(inbuf, "BarrettHand Firmware\n", nin)
    assert re.search(rb"Version \d+\.\d+\.\d+", response)
    assert client.barrett("VERS") == "Version 4.4.3 (barrett-twin emulator)"


def test_barrett_init_hand_and_supervisory_calls(client: RawClient):
    client.barrett("HI", MOTION_GUARD_S)
    assert ints(client.barrett("FGET P")) == [0, 0, 0, 0]
    client.barrett("GFSET MCV 80")
    assert ints(client.barrett("1FGET MCV")) == [80]
    assert ints(client.barrett("PGET TEMP"))[0] > 0
    client.barrett("GM 4000", MOTION_GUARD_S)  # within MPE of its target, or the reply is ERR 16
    assert all(abs(p - 4000) <= 50 for p in ints(client.barrett("GFGET P")))
    client.barrett("GHOME", MOTION_GUARD_S)
    client.barrett("SHOME", MOTION_GUARD_S)


def test_barrett_realtime_start_cycles_and_abort(client: RawClient):
    client.barrett("HI", MOTION_GUARD_S)
    client.barrett(
        "1234FSET LCV 1 LCVC 1 LCPG 1 LCT 0 LFV 1 LFVC 1 LFS 1 LFAP 1 LFDP 0 LFDPC 1 LFBP 0 LFAIN 0"
    )
    client.barrett("PSET LFT 1 LFDPD 0")
    for prefix in "123S":  # RTStart reads the flags back, motor by motor
        assert ints(client.barrett(f"{prefix}FGET LCV LCPG LCT LFV LFS LFAP LFDP LFBP LFAIN")) == [
            1, 1, 0, 1, 1, 1, 0, 0, 0,
        ]  # fmt: skip
    assert ints(client.barrett("PGET LFT")) == [1]
    client.write(b"1234LOOP\r")
    assert client.read_exactly(len("1234LOOP") + 1) == b"1234LOOP*"
    block = b"C" + bytes([20, 50]) * 3 + bytes([0, 50])
    for _ in range(30):
        client.write(block)
        reply = client.read_exactly(1 + 4 * (1 + 1 + 2) + 1)  # LFV, LFS, LFAP per motor, then LFT
        assert reply[:1] == b"*"
    positions = [struct.unpack_from(">H", reply, 1 + 4 * m + 2)[0] for m in range(3)]
    assert min(positions) > 0  # the fingers closed under the velocity command
    client.write(b"\x03")  # RTAbort
    assert client.read_until(PROMPT).endswith(LE + PROMPT)


def test_barrett_rtabort_after_an_error_in_realtime_sees_a_prompt():
    emu = make_hand_emulator(None, baud=38400, faults="err@4:8192")
    client = RawClient(emu.serve_pty())
    try:
        client.write(b"\r")
        client.read_until(PROMPT)
        client.barrett("HI", MOTION_GUARD_S)
        client.barrett("1234FSET LCV 1 LCVC 1 LCPG 1 LCT 0 LFV 0 LFS 0 LFAP 1 LFDP 0 LFBP 0 LFAIN 0")
        client.barrett("PSET LFT 0")
        client.write(b"1234LOOP\r")
        assert client.read_exactly(len("1234LOOP") + 1) == b"1234LOOP*"
        block = b"C" + bytes([0, 10]) * 4
        for _ in range(3):
            client.write(block)
            assert client.read_exactly(9)[:1] == b"*"
        client.write(block + block)  # the failing block, and one already sent behind it
        reply = client.read_until(LE + PROMPT)
        assert re.fullmatch(rb"\n\rERR (\d+)\n\r=> ", reply) and b"\n\rERR 8192" in reply
        client.write(b"\x03")  # RTAbort: the block behind the error must not swallow it
        assert client.read_until(PROMPT) == LE + PROMPT
        assert len(ints(client.barrett("FGET P"))) == 4  # back in Supervisory mode
    finally:
        client.close()
        emu.close()


# --- libgripper ---------------------------------------------------------------------------------------


def test_libgripper_connect_ctrl_c_is_answered_with_a_prompt(client: RawClient):
    client.write(b"\x03")
    assert client.read_until(PROMPT) == LE + PROMPT
    client.write(b"1FG\x03")  # a half-typed line is dropped by Ctrl-C, not completed by the next CR
    assert client.read_until(PROMPT) == LE + PROMPT
    assert ints(client.libgripper("1FGET MCV")) == [100]


def test_libgripper_initialize_and_realtime(client: RawClient):
    status = ints(client.libgripper("1234FGET S"))
    assert len(status) == 4 and all(status)  # not initialized: libgripper sends HI
    client.libgripper("HI", MOTION_GUARD_S)
    assert ints(client.libgripper("1234FGET S")) == [0, 0, 0, 0]  # a reconnect skips HI
    client.libgripper("SFSET FPG 5 FIP 1 FDZ 100")
    client.libgripper("GFSET FPG 10 FIP 0 FDZ 0")
    assert ints(client.libgripper("SFGET FPG FIP FDZ")) == [5, 1, 100]
    for prefix in "123":
        client.libgripper(
            f"{prefix}FSET LCV 1 LCVC 2 LCPG 0 LCT 0 LFV 0 LFVC 1 LFAP 1 LFS 0 LFDP 0 LFBP 0 LFAIN 0"
        )
    client.libgripper("SFSET LCV 0 LCVC 0 LCPG 0 LCT 1 LFV 0 LFVC 1 LFAP 1 LFS 0 LFDP 0 LFBP 0 LFAIN 0")
    client.libgripper("PSET LFT 1")
    client.write(b"1234LOOP\r")
    assert client.read_exactly(len("1234LOOP")) == b"1234LOOP"
    assert client.read_exactly(1) == b"*"
    client.write(b"A")
    assert client.read_exactly(10)[:1] == b"*"  # '*', LFAP x 4, LFT (1 byte)
    for _ in range(30):
        client.write(b"C" + bytes([16, 16, 16]) + struct.pack(">h", 100))  # LCV x 3, spread LCT
        reply = client.read_exactly(10)
        assert reply[:1] == b"*"
    assert struct.unpack_from(">H", reply, 7)[0] > 0  # the spread moved under LCT
    client.write(b"\x03")
    assert client.read_until(PROMPT).endswith(PROMPT)


# --- the property table, as the manual gives it -------------------------------------------------------

MANUAL_DEFAULTS = {  # name: (finger, spread), BH8-series manual §5.3
    "LCV": (1, 1), "LCVC": (1, 1), "LCPG": (1, 1), "LFV": (1, 1), "LFVC": (1, 1), "LFS": (1, 1),
    "LFAP": (1, 1), "LFDP": (1, 1), "LFDPC": (1, 1), "MPE": (50, 50), "TSTOP": (30, 30),
    "FPG": (10, 10), "FIP": (0, 0), "FDZ": (0, 0), "CT": (17000, 3150), "OT": (0, 0),
    "DP": (8500, 1575), "DS": (1700, 315), "MCV": (100, 60), "MOV": (100, 60), "IVEL": (300, 150),
    "IHIT": (2, 0), "IOFF": (50, 0), "HOLD": (0, 1), "ACCEL": (4, 2), "SAMPLE": (31, 31),
    "BDAT": (1500, 0), "EN": (1, 1), "HSG": (256, 256), "LSG": (256, 256), "MSG": (256, 256),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(MANUAL_DEFAULTS))
def test_the_manuals_defaults(client: RawClient, name: str):
    finger, spread = MANUAL_DEFAULTS[name]
    assert ints(client.barrett(f"FGET {name}")) == [finger, finger, finger, spread]


def test_ranges_unknown_names_and_version(client: RawClient):
    client.barrett("GFSET CT 65535 LCVC 0")
    assert ints(client.barrett("1FGET CT LCVC")) == [65535, 0]
    client.write(b"1FSET MCV 90 NOSUCH 1 MOV 70\r")  # one unknown name: ERR 64, the others applied
    assert client.read_until(PROMPT) == b"1FSET MCV 90 NOSUCH 1 MOV 70" + LE + b"ERR 64" + LE + PROMPT
    assert ints(client.barrett("1FGET MCV MOV")) == [90, 70]
    client.write(b"FSET LCVC 256\r")
    assert client.read_until(PROMPT).endswith(b"ERR 128" + LE + PROMPT)
    client.write(b"FSET P 5\r")
    assert client.read_until(PROMPT).endswith(b"ERR 256" + LE + PROMPT)
    assert len(ints(client.barrett("PGET TEMP UPSECS SN"))) == 3
    client.barrett("HI", MOTION_GUARD_S)
    assert (
        len(ints(client.barrett("FGET FIP FDZ ACCEL BDAT BS OD EN IHIT SAMPLE IOFF IVEL SGFLIP MSG"))) == 52
    )


# --- replies never wait for the physics ---------------------------------------------------------------


def test_a_realtime_reply_comes_while_the_physics_is_held(emulator: HandEmulator, client: RawClient):
    """The twin's lock held by this test (the physics thread cannot step): the hand still answers a
    block, from the last published state, and the control waits for the physics to take it."""
    client.barrett("HI", MOTION_GUARD_S)
    client.barrett("1234FSET LCV 1 LCVC 1 LCPG 1 LCT 0 LFV 0 LFS 0 LFAP 1 LFDP 0 LFBP 0 LFAIN 0")
    client.barrett("PSET LFT 0")
    client.write(b"1234LOOP\r")
    assert client.read_exactly(len("1234LOOP") + 1) == b"1234LOOP*"
    twin = emulator.twin
    released = threading.Event()
    with twin.lock:
        before = twin.backend.world.time_s
        client.write(b"C" + bytes([40, 60]) * 4)
        reply = client.read_exactly(9)
        assert twin.backend.world.time_s == before  # no step was taken meanwhile
        assert reply[:1] == b"*"
        assert twin.pending_actions == 1  # the control is waiting for the physics
        released.set()
    deadline = time.monotonic() + GUARD_S
    while twin.pending_actions and time.monotonic() < deadline:
        time.sleep(0.01)
    assert twin.pending_actions == 0 and released.is_set()
    client.write(b"\x03")
    client.read_until(PROMPT)
