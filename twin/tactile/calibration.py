"""Taxel calibration: 7-point data -> a least-squares line per taxel -> a look-up table file (eq. 5),
and the reaction force of a pad (eq. 6).

Eq. 5: P_i = a_i * count_i + b_i (kPa). Eq. 6: F_R,k = sum over the active taxels i of pad k of
P_i * A_i. Files are CSV with a comment header, so a lab can drop in the manufacturer's data:
  points file: `taxel,pressure_kpa,count`, 7 rows per taxel (the manufacturer's calibration points)
  table file:  `taxel,a_kpa_per_count,b_kpa`, one row per taxel (what the conversion loads)
Every problem with a file is reported as `file:line: what is wrong`.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from twin.interface.devices import N_TAXELS, TAXEL_COUNT_MAX
from twin.interface.errors import ConfigError
from twin.tactile.layout import LAYOUT
from twin.validation import parse_decimal

POINTS_HEADER = ("taxel", "pressure_kpa", "count")
TABLE_HEADER = ("taxel", "a_kpa_per_count", "b_kpa")
CALIBRATION_POINTS_KPA = (0.0, 25.0, 50.0, 100.0, 150.0, 200.0, 300.0)
"""The 7 reference pressures of the manufacturer-style calibration (hardware_facts §4: 7 points)."""
ACTIVE_THRESHOLD_KPA = 0.5
"""A taxel is in contact (active in eq. 6) above this pressure: 10 sigma of the sim's reading noise
(4 counts x 0.0125 kPa/count), well above its calibration error; raise it for a noisier real pad."""


class CalibrationFileError(ConfigError):
    """A calibration file that is missing or cannot be parsed; the message names file and line."""


@dataclass(frozen=True)
class TaxelCalibration:
    """Eq. 5 per taxel: pressure_kpa = a * count + b."""

    a_kpa_per_count: NDArray[np.float64]
    b_kpa: NDArray[np.float64]
    source: str = ""

    def __post_init__(self) -> None:
        if self.a_kpa_per_count.shape != (N_TAXELS,) or self.b_kpa.shape != (N_TAXELS,):
            raise ValueError(f"a calibration has {N_TAXELS} lines")
        if not np.all(self.a_kpa_per_count > 0):
            raise ValueError("every taxel's slope a must be > 0")

    def to_kpa(self, counts: ArrayLike) -> NDArray[np.float64]:
        """Eq. 5: raw counts (..., 162) -> pressure (kPa)."""
        return self.a_kpa_per_count * np.asarray(counts, dtype=float) + self.b_kpa

    def to_counts(self, pressure_kpa: ArrayLike) -> NDArray[np.float64]:
        """Inverse of eq. 5, not rounded or clipped (the device model quantizes and saturates)."""
        return (np.asarray(pressure_kpa, dtype=float) - self.b_kpa) / self.a_kpa_per_count

    def saturation_kpa(self) -> NDArray[np.float64]:
        """(162,) pressure at which each taxel's count saturates."""
        return self.to_kpa(np.full(N_TAXELS, TAXEL_COUNT_MAX))


def fit_lines(
    taxel: ArrayLike, pressure_kpa: ArrayLike, counts: ArrayLike, source: str = ""
) -> TaxelCalibration:
    """Least-squares line pressure = a * count + b through each taxel's calibration points."""
    taxel = np.asarray(taxel, dtype=int)
    p = np.asarray(pressure_kpa, dtype=float)
    c = np.asarray(counts, dtype=float)
    a = np.empty(N_TAXELS)
    b = np.empty(N_TAXELS)
    for i in range(N_TAXELS):
        sel = taxel == i
        if sel.sum() < 2:
            raise CalibrationFileError(f"{source}: taxel {i} has {sel.sum()} calibration points, needs >= 2")
        design = np.column_stack([c[sel], np.ones(sel.sum())])
        (a[i], b[i]), *_ = np.linalg.lstsq(design, p[sel], rcond=None)
    if not np.all(a > 0):
        bad = int(np.flatnonzero(a <= 0)[0])
        raise CalibrationFileError(
            f"{source}: taxel {bad}: pressure does not rise with count (a = {a[bad]:.3g})"
        )
    return TaxelCalibration(a, b, source)


def _rows(path: Path, header: tuple[str, ...]) -> list[tuple[int, list[str]]]:
    """(line number, fields) of a CSV file with `header`, comments (#) skipped."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise CalibrationFileError(f"{path}: no such calibration file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationFileError(f"{path}: cannot read ({exc})") from None
    rows = []
    seen_header = False
    for lineno, fields in enumerate(csv.reader(text.splitlines()), start=1):
        if not fields or fields[0].lstrip().startswith("#"):
            continue
        fields = [f.strip() for f in fields]
        if not seen_header:
            if tuple(fields) != header:
                raise CalibrationFileError(f"{path}:{lineno}: expected the header {','.join(header)}")
            seen_header = True
            continue
        if len(fields) != len(header):
            raise CalibrationFileError(f"{path}:{lineno}: expected {len(header)} fields, got {len(fields)}")
        rows.append((lineno, fields))
    if not seen_header:
        raise CalibrationFileError(f"{path}: empty calibration file (no {','.join(header)} header)")
    return rows


def _number(path: Path, lineno: int, text: str, kind: type = float) -> float:
    try:
        value = parse_decimal(text, kind)
    except ValueError:
        if text.strip().lower().lstrip("+-") in ("nan", "inf", "infinity"):
            raise CalibrationFileError(f"{path}:{lineno}: {text!r} is not finite") from None
        raise CalibrationFileError(f"{path}:{lineno}: {text!r} is not a number (plain decimals)") from None
    if not np.isfinite(value):
        raise CalibrationFileError(f"{path}:{lineno}: {text!r} is not finite")
    return value


def _taxel(path: Path, lineno: int, text: str) -> int:
    i = int(_number(path, lineno, text, int))
    if not 0 <= i < N_TAXELS:
        raise CalibrationFileError(f"{path}:{lineno}: taxel {i} outside 0-{N_TAXELS - 1}")
    return i


def load_points(path: Path | str) -> TaxelCalibration:
    """Read a points file and fit the per-taxel lines."""
    path = Path(path)
    taxel, pressure, counts = [], [], []
    for lineno, (t, p, c) in _rows(path, POINTS_HEADER):
        taxel.append(_taxel(path, lineno, t))
        pressure.append(_number(path, lineno, p))
        counts.append(_number(path, lineno, c))
    return fit_lines(taxel, pressure, counts, str(path))


def load_table(path: Path | str) -> TaxelCalibration:
    """Read a look-up table file: one line per taxel, each taxel exactly once."""
    path = Path(path)
    a = np.full(N_TAXELS, np.nan)
    b = np.full(N_TAXELS, np.nan)
    for lineno, (t, ta, tb) in _rows(path, TABLE_HEADER):
        i = _taxel(path, lineno, t)
        if not np.isnan(a[i]):
            raise CalibrationFileError(f"{path}:{lineno}: taxel {i} appears twice")
        a[i] = _number(path, lineno, ta)
        b[i] = _number(path, lineno, tb)
        if a[i] <= 0:
            raise CalibrationFileError(f"{path}:{lineno}: slope a must be > 0, got {ta}")
    missing = np.flatnonzero(np.isnan(a))
    if missing.size:
        raise CalibrationFileError(f"{path}: no line for taxel(s) {', '.join(map(str, missing[:8]))}")
    return TaxelCalibration(a, b, str(path))


def load_calibration(files: dict[str, Path]) -> TaxelCalibration:
    """Eq. 5 lines from a set of calibration files: the table if there is one, else the points."""
    if "tactile_table" in files:
        return load_table(files["tactile_table"])
    if "tactile_points" in files:
        return load_points(files["tactile_points"])
    raise CalibrationFileError(
        "tactile pads without a calibration file: name one in the rig's [calibration] table"
    )


def write_table(calibration: TaxelCalibration, path: Path | str, note: str = "") -> Path:
    """Write the look-up table file (the slopes with enough digits to round-trip a count)."""
    path = Path(path)
    lines = [
        f"# tactile calibration, eq. 5: pressure_kPa = a * count + b. {note}".rstrip(),
        ",".join(TABLE_HEADER),
    ]
    lines += [
        f"{i},{calibration.a_kpa_per_count[i]:.10g},{calibration.b_kpa[i]:.10g}" for i in range(N_TAXELS)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_points(
    taxel: ArrayLike, pressure_kpa: ArrayLike, counts: ArrayLike, path: Path | str, note: str = ""
) -> Path:
    """Write a points file (7 manufacturer-style points per taxel)."""
    path = Path(path)
    lines = [
        f"# tactile calibration points (pressure applied, count read). {note}".rstrip(),
        ",".join(POINTS_HEADER),
    ]
    lines += [f"{int(t)},{p:.6g},{int(c)}" for t, p, c in zip(taxel, pressure_kpa, counts, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def active(pressure_kpa: ArrayLike, threshold_kpa: float = ACTIVE_THRESHOLD_KPA) -> NDArray[np.bool_]:
    """Taxels in contact: pressure above the threshold."""
    return np.asarray(pressure_kpa) > threshold_kpa


def pad_forces_n(pressure_kpa: ArrayLike, threshold_kpa: float = ACTIVE_THRESHOLD_KPA) -> NDArray[np.float64]:
    """Eq. 6 per pad: sum of P_i * A_i over its active taxels, in N; (..., 7) in LAYOUT.pads order."""
    p = np.asarray(pressure_kpa, dtype=float)
    force = np.where(active(p, threshold_kpa), p * 1e3 * LAYOUT.area_m2, 0.0)
    out = np.zeros((*p.shape[:-1], len(LAYOUT.pads)))
    for k in range(len(LAYOUT.pads)):
        out[..., k] = force[..., LAYOUT.pad_index == k].sum(axis=-1)
    return out


def active_counts(pressure_kpa: ArrayLike, threshold_kpa: float = ACTIVE_THRESHOLD_KPA) -> NDArray[np.int64]:
    """Taxels in contact per pad, (..., 7)."""
    act = active(pressure_kpa, threshold_kpa)
    return np.stack([act[..., LAYOUT.pad_index == k].sum(axis=-1) for k in range(len(LAYOUT.pads))], axis=-1)
