"""`bh8emu://[?object=NAME&baud=N&faults=SPEC&seed=N]`: a BH8-262 emulator on the twin, in process.

Handy for notebooks and tests: the driver talks to the emulator over a socket pair with the same
byte-level behaviour (baud pacing, faults) as `twin emulate hand` on a pty or TCP port.
"""

from __future__ import annotations

import urllib.parse

from serial.serialutil import SerialException
from serial.urlhandler import protocol_socket


class Serial(protocol_socket.Serial):
    """A pyserial port whose far end is a fresh twin-backed hand emulator."""

    def from_url(self, url: str) -> dict[str, str]:
        """The query parameters of a bh8emu:// URL."""
        parts = urllib.parse.urlsplit(url)
        if parts.scheme != "bh8emu":
            raise SerialException(f"expected a bh8emu:// URL, got {url!r}")
        query = dict(urllib.parse.parse_qsl(parts.query))
        unknown = set(query) - {"object", "baud", "faults", "seed"}
        if unknown:
            raise SerialException(f"{url}: unknown parameter(s) {', '.join(sorted(unknown))}")
        return query

    def open(self) -> None:
        """Start the emulator and connect to it."""
        from hardware.bh262.emulator import make_hand_emulator

        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        self.logger = None
        query = self.from_url(self.portstr)
        obj = query.get("object", "block")
        try:
            self.emulator = make_hand_emulator(
                None if obj in ("", "none") else obj,
                baud=int(query.get("baud", 9600)),
                faults=query.get("faults"),
                seed=int(query.get("seed", 0)),
            )
        except (ValueError, KeyError) as exc:
            raise SerialException(f"{self.portstr}: {exc}") from None
        self._socket = self.emulator.serve_socketpair()
        self._socket.setblocking(False)
        self._reconfigure_port()
        self.is_open = True
        self.reset_input_buffer()

    def close(self) -> None:
        """Close the connection and stop the emulator."""
        super().close()
        emulator = getattr(self, "emulator", None)
        if emulator is not None:
            emulator.close()
            self.emulator = None
