"""The BH8-262's motor and global properties: names, factory defaults, writable ranges.

From the BH8-series manual (firmware 4.3x, §5.3-5.4) and the property table of Barrett's BHand API
4.4.3 (`BHandBH8_262.cpp`), which agree on every name. Where they disagree on a range, the wider one is
taken, because real clients send it: LCVC, LFVC and LFDPC are 0-255 in §5.3.3 and in the API (Table 4
of the manual says 1-255; libgripper sends `LCVC 0`). CT, DP, DS, OT, MPE, ACCEL, IHIT, IOFF and
TSTOP are 0-65535 (the manual: "can be set as high as 65,535"); the motors stop at their joints.
"""

from __future__ import annotations

from dataclasses import dataclass

UINT16 = (0, 65_535)
UINT8 = (0, 255)
FLAG = (0, 1)
VELOCITY = (16, 4080)


@dataclass(frozen=True)
class Property:
    """One property: defaults for a finger and the spread, and the writable range (None: read-only)."""

    finger: int
    spread: int
    writable: tuple[int, int] | None


def _rw(finger: int, spread: int | None = None, bounds: tuple[int, int] = UINT16) -> Property:
    return Property(finger, finger if spread is None else spread, bounds)


_READ_ONLY = Property(0, 0, None)

MOTOR_PROPERTIES: dict[str, Property] = {
    # Movement (§5.3.1)
    "BDAT": _rw(1500, 0, (0, 20_000)),
    "BS": _rw(0, bounds=FLAG),
    "DP": _rw(8500, 1575),
    "DS": _rw(1700, 315),
    "HSG": _rw(256, bounds=(0, 256)),
    "LSG": _rw(256, bounds=(0, 256)),
    "MSG": _rw(256, bounds=(0, 256)),  # the old name of HSG: both name one value (see ALIASES)
    "MOV": _rw(100, 60, VELOCITY),
    "MCV": _rw(100, 60, VELOCITY),
    # Status (§5.3.2): read-only, answered from the twin
    "BD": _READ_ONLY,
    "BP": _READ_ONLY,
    "OD": _READ_ONLY,
    "P": _READ_ONLY,
    "S": _READ_ONLY,
    "SG": _READ_ONLY,
    # RealTime (§5.3.3): every flag 1 out of the factory, LCT/LFBP/LFAIN (4.4 only) 0
    "LCV": _rw(1, bounds=FLAG),
    "LCVC": _rw(1, bounds=UINT8),
    "LCPG": _rw(1, bounds=FLAG),
    "LCT": _rw(0, bounds=FLAG),
    "LFV": _rw(1, bounds=FLAG),
    "LFVC": _rw(1, bounds=UINT8),
    "LFS": _rw(1, bounds=FLAG),
    "LFAP": _rw(1, bounds=FLAG),
    "LFDP": _rw(1, bounds=FLAG),
    "LFDPC": _rw(1, bounds=UINT8),
    "LFBP": _rw(0, bounds=FLAG),
    "LFAIN": _rw(0, bounds=FLAG),
    # Advanced (§5.3.4)
    "ACCEL": _rw(4, 2),
    "CT": _rw(17_000, 3150),
    "EN": _rw(1, bounds=FLAG),
    "FDZ": _rw(0, bounds=UINT8),
    "FIP": _rw(0, bounds=UINT8),
    "FPG": _rw(10, bounds=UINT8),
    "HOLD": _rw(0, 1, FLAG),
    "IHIT": _rw(2, 0),
    "IOFF": _rw(50, 0),
    "IVEL": _rw(300, 150, VELOCITY),
    "MPE": _rw(50),
    "OT": _rw(0),
    "SAMPLE": _rw(31, bounds=(15, 255)),
    "SGFLIP": _rw(0, bounds=FLAG),
    "TSTOP": _rw(30),
}
ALIASES = {"MSG": "HSG"}
"""Names that read and write another property's value (§5.3.1: MSG is HSG)."""

GLOBAL_PROPERTIES: dict[str, Property] = {
    "BAUD": _rw(96, bounds=(6, 384)),  # only 6, 12, 24, 48, 96, 192, 384 are accepted
    "LFT": _rw(0, bounds=FLAG),
    "LFDPD": _rw(0, bounds=FLAG),
    "OTEMP": _rw(0, bounds=(0, 1250)),
    "TEMP": _READ_ONLY,
    "PTEMP": _READ_ONLY,
    "UPSECS": _READ_ONLY,
    "SN": _READ_ONLY,
}
