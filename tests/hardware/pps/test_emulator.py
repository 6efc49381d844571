"""The PPS tactile emulator against its own bad arguments and an abandoned client."""

from __future__ import annotations

import socket
import time

import pytest
from twin.hardware.emulation import BUSY_REPLY
from twin.hardware.pps.emulator import FaultPlan, make_tactile_emulator
from twin.hardware.pps.frame import FRAME_SIZE, SYNC

from twin.interface.errors import ConfigError

HANG_GUARD_S = 10.0


@pytest.mark.parametrize(
    "spec",
    ["stall@3:nan", "stall@3:inf", "stall@3:-1", "stall@3:1e9", "stall@0", "corrupt@3:1", "drop@2,stall@2"],
)
def test_bad_tactile_fault_specs_are_refused_in_one_line_naming_the_option(spec: str):
    with pytest.raises(ConfigError) as err:
        FaultPlan.parse(spec, option="--tactile-faults")
    assert str(err.value).startswith("--tactile-faults: ") and "\n" not in str(err.value)


def test_a_finite_stall_in_range_is_accepted():
    assert FaultPlan.parse("stall@3:2.5").at(3).arg == 2.5


def _first_bytes(address: tuple[str, int], n: int, linger_s: float = 0.0) -> bytes:
    """The first n bytes a new client reads (fewer if the port closes); it stays linger_s, then leaves."""
    with socket.create_connection(address, timeout=HANG_GUARD_S) as sock:
        data = b""
        deadline = time.monotonic() + HANG_GUARD_S
        while len(data) < n and time.monotonic() < deadline:
            chunk = sock.recv(n - len(data))
            if not chunk:
                break
            data += chunk
        time.sleep(linger_s)
        return data


def test_a_client_gone_during_a_stall_for_good_frees_the_port():
    """stall@3 without a time stalls for good: a client leaving then must not keep the port (before,
    the next one waited forever; with one client at a time it would be refused as busy)."""
    with make_tactile_emulator("ramp", faults="stall@3") as emulator:
        host, port = emulator.serve_tcp(0).removeprefix("socket://").rsplit(":", 1)
        address = (host, int(port))
        first = _first_bytes(address, 2 * FRAME_SIZE, linger_s=0.5)  # two frames, the stall, it leaves
        assert first.startswith(SYNC) and len(first) == 2 * FRAME_SIZE
        second = _first_bytes(address, FRAME_SIZE)
        assert second != BUSY_REPLY[: len(second)] and second.startswith(SYNC)
