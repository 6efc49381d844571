"""`bh8emu://[?object=NAME&baud=N&faults=SPEC&seed=N]`: a BH8-262 emulator on the twin, in process.

Handy for notebooks and tests: the driver talks to the emulator over a socket pair with the same
byte-level behaviour (baud pacing, faults) as `twin emulate hand` on a pty or TCP port.
"""

from __future__ import annotations

from twin.hardware.emulation import EmulatorPort, PortServer


class Serial(EmulatorPort):
    """A pyserial port whose far end is a fresh twin-backed hand emulator."""

    scheme = "bh8emu"
    parameters = frozenset({"object", "baud", "faults", "seed"})

    def _make_emulator(self, query: dict[str, str]) -> PortServer:
        from twin.hardware.bh262.emulator import make_hand_emulator

        obj = query.get("object", "block")
        return make_hand_emulator(
            None if obj in ("", "none") else obj,
            baud=int(query.get("baud", 9600)),
            faults=query.get("faults"),
            seed=int(query.get("seed", 0)),
        )
