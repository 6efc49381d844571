"""The emulated hand's physics thread: it survives a quiet window (held open for a due RealTime reply)
ending between two reads of the clock, as happens on a loaded machine."""

import threading
import time
import types

import pytest
from twin.hardware.bh262 import firmware
from twin.hardware.bh262.firmware import RealTimeTwin

from twin.sim.backend import SimBackend

TICK_S = 1e-3
"""How far the fake clock moves at each read: every read of it lands later than the one before."""


class _TickingClock:
    """Monotonic time that advances TICK_S at every read, so that no two reads agree (a starved thread's
    view of the clock, made certain)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._t = time.monotonic()

    def monotonic(self) -> float:
        with self._lock:
            self._t += TICK_S
            return self._t

    def peek(self) -> float:
        with self._lock:
            return self._t


def test_a_quiet_window_ending_between_two_clock_reads_does_not_stop_the_physics(monkeypatch):
    """The CI failure 'the twin stopped: ValueError: sleep length must be non-negative': the thread
    checked it was inside the window, then read the clock again for the sleep, past the window's end."""
    clock = _TickingClock()
    monkeypatch.setattr(firmware, "time", types.SimpleNamespace(monotonic=clock.monotonic, sleep=time.sleep))
    twin = RealTimeTwin(SimBackend(None, seed=0))
    twin.start()
    try:
        for i in range(40):  # each ends half a tick past a read, its length odd or even in reads
            end = clock.peek() + (10.5 + i % 2) * TICK_S
            twin.keep_quiet(0.0, end)
            deadline = time.monotonic() + 5.0
            while clock.peek() < end + 2 * TICK_S and twin.failure is None and time.monotonic() < deadline:
                time.sleep(1e-4)
            assert twin.failure is None, twin.failure
            assert clock.peek() >= end, "the physics thread stopped reading the clock"
    finally:
        twin.stop()
    if twin.failure is not None:
        pytest.fail(twin.failure)
