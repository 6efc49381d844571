"""`twin emulate rig`: every emulated device of the rig on one twin, with the rig.toml to reach them.

The hand (BH8-262 on a serial line) and the tactile pads (the PPS interface streaming frames) are
served from the same real-time twin, so the pads feel what the emulated hand squeezes; the pads'
calibration files are the twin's simulated ones, written as a manufacturer would ship them. The
cameras join here when their emulator lands.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hardware.bh262.emulator import HandEmulator, make_hand_emulator
from hardware.bh262.firmware import RealTimeTwin
from hardware.pps.emulator import TactileEmulator
from hardware.rig_config import rig_toml


def twin_tactile_source(twin: RealTimeTwin) -> Callable[[], np.ndarray]:
    """A tactile emulator source that scans the twin's pads (under the twin's lock)."""
    tactile = twin.backend.tactile
    if tactile is None:
        raise ValueError("the twin has no tactile pads")

    def scan() -> np.ndarray:
        with twin.lock:
            return tactile.read().counts

    return scan


class RigEmulator:
    """The hand and tactile emulators on one twin."""

    def __init__(
        self,
        object_name: str | None = "block",
        *,
        baud: int = 9600,
        faults: str | None = None,
        tactile_faults: str | None = None,
        seed: int = 0,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        self.hand: HandEmulator = make_hand_emulator(
            object_name, baud=baud, faults=faults, seed=seed, on_event=on_event
        )
        self.tactile = TactileEmulator(
            twin_tactile_source(self.hand.twin),
            rate_hz=self.hand.twin.backend.tactile.config.rate_hz,
            faults=tactile_faults,
            on_event=on_event,
        )
        self.baud = baud
        self._tmp: tempfile.TemporaryDirectory | None = None

    def serve(self, where: str = "pty") -> tuple[str, str]:
        """Serve both on ptys (`pty`) or TCP (`tcp:PORT`: the hand on PORT, the pads on PORT + 1;
        `tcp:0` picks free ports); returns the two addresses."""
        if where == "pty":
            hand = self.hand.serve_pty()
        else:
            port = int(where.split(":", 1)[1])
            hand = self.hand.serve_tcp(port)
            port = 0 if port == 0 else port + 1
        self.hand.twin.start()  # the pads scan the twin from their first frame on
        tactile = self.tactile.serve_pty() if where == "pty" else self.tactile.serve_tcp(port)
        return hand, tactile

    def write_rig_file(self, path: Path | None) -> Path:
        """The twin's tactile calibration beside a rig.toml that names both ports; returns the rig.toml."""
        if path is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="twin-rig-")
            path = Path(self._tmp.name) / "rig.toml"
        path.parent.mkdir(parents=True, exist_ok=True)
        files = self.hand.twin.backend.tactile.sensor.write_files(path.parent / "calibration")
        table = files["tactile_table"].relative_to(path.parent)
        text = rig_toml(
            self.hand.address, baud=self.baud, tactile_url=self.tactile.address, tactile_table=str(table)
        )
        path.write_text(text)
        return path

    def close(self) -> None:
        """Stop both emulators and the twin."""
        self.tactile.close()
        self.hand.close()
        if self._tmp is not None:
            self._tmp.cleanup()

    def __enter__(self) -> RigEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
