"""`ppsemu://[?source=NAME&rate=HZ&baud=N&faults=SPEC&first_sequence=N]`: a PPS tactile emulator in process.

Handy for notebooks and tests: the driver reads the emulator over a socket pair with the same
byte-level behaviour (scan rate, baud pacing, faults) as the emulator on a pty or TCP port. NAME is one
of hardware.pps.emulator.SOURCES (default `ramp`).
"""

from __future__ import annotations

import urllib.parse

from serial.serialutil import SerialException
from serial.urlhandler import protocol_socket

from twin.interface.errors import ConfigError

PARAMETERS = {"source", "rate", "baud", "faults", "first_sequence"}


class Serial(protocol_socket.Serial):
    """A pyserial port whose far end is a fresh tactile emulator."""

    def from_url(self, url: str) -> dict[str, str]:
        """The query parameters of a ppsemu:// URL."""
        parts = urllib.parse.urlsplit(url)
        if parts.scheme != "ppsemu":
            raise SerialException(f"expected a ppsemu:// URL, got {url!r}")
        query = dict(urllib.parse.parse_qsl(parts.query))
        unknown = set(query) - PARAMETERS
        if unknown:
            raise SerialException(f"{url}: unknown parameter(s) {', '.join(sorted(unknown))}")
        return query

    def open(self) -> None:
        """Start the emulator and connect to it."""
        from hardware.pps.emulator import DEFAULT_BAUD, make_tactile_emulator

        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        self.logger = None
        query = self.from_url(self.portstr)
        try:
            self.emulator = make_tactile_emulator(
                query.get("source", "ramp"),
                rate_hz=float(query.get("rate", 30.0)),
                baud=int(query.get("baud", DEFAULT_BAUD)),
                faults=query.get("faults"),
                first_sequence=int(query.get("first_sequence", 0)),
            )
        except (ValueError, ConfigError) as exc:
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
