"""`ppsemu://[?source=NAME&rate=HZ&baud=N&faults=SPEC&first_sequence=N]`: a PPS tactile emulator in process.

Handy for notebooks and tests: the driver reads the emulator over a socket pair with the same
byte-level behaviour (scan rate, baud pacing, faults) as the emulator on a pty or TCP port. NAME is one
of twin.hardware.pps.emulator.SOURCES (default `ramp`).
"""

from __future__ import annotations

from twin.hardware.emulation import EmulatorPort, PortServer


class Serial(EmulatorPort):
    """A pyserial port whose far end is a fresh tactile emulator."""

    scheme = "ppsemu"
    parameters = frozenset({"source", "rate", "baud", "faults", "first_sequence"})

    def _make_emulator(self, query: dict[str, str]) -> PortServer:
        from twin.hardware.pps.emulator import DEFAULT_BAUD, make_tactile_emulator

        return make_tactile_emulator(
            query.get("source", "ramp"),
            rate_hz=float(query.get("rate", 30.0)),
            baud=int(query.get("baud", DEFAULT_BAUD)),
            faults=query.get("faults"),
            first_sequence=int(query.get("first_sequence", 0)),
        )
