"""Eq. 5 per taxel from 7-point data, look-up table files, clear errors for bad files; eq. 6."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twin.interface.devices import TAXEL_COUNT_MAX
from twin.sim.tactile import SimTactileSensor
from twin.tactile.calibration import (
    CalibrationFileError,
    TaxelCalibration,
    fit_lines,
    load_points,
    load_table,
    pad_forces_n,
    write_points,
    write_table,
)
from twin.tactile.layout import LAYOUT

SENSOR = SimTactileSensor.generate(seed=3)


def test_least_squares_recovers_noise_free_lines():
    true = SENSOR.true
    taxel = SENSOR.points_taxel
    kpa = SENSOR.points_kpa
    counts = (kpa - true.b_kpa[taxel]) / true.a_kpa_per_count[taxel]  # exact, unrounded readings
    fitted = fit_lines(taxel, kpa, counts)
    assert np.allclose(fitted.a_kpa_per_count, true.a_kpa_per_count, rtol=1e-9)
    assert np.allclose(fitted.b_kpa, true.b_kpa, atol=1e-6)


def test_simulated_lines_have_a_realistic_spread_and_calibration_error():
    a = SENSOR.true.a_kpa_per_count
    assert 0.03 < a.std() / a.mean() < 0.15  # gains differ from taxel to taxel
    fitted = fit_lines(SENSOR.points_taxel, SENSOR.points_kpa, SENSOR.points_counts)
    err_kpa = np.abs(fitted.to_kpa(SENSOR.true.to_counts(100.0)) - 100.0)
    assert 0 < err_kpa.max() < 2.0  # the 7 noisy points leave a small error, as on a real pad


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, TAXEL_COUNT_MAX - 1), min_size=162, max_size=162))
def test_counts_to_kpa_to_counts_round_trips_within_one_lsb(counts):
    table = fit_lines(SENSOR.points_taxel, SENSOR.points_kpa, SENSOR.points_counts)
    back = table.to_counts(table.to_kpa(np.array(counts)))
    assert np.all(np.abs(back - counts) <= 1)


def test_round_trip_through_the_files(tmp_path: Path):
    files = SENSOR.write_files(tmp_path)
    table = load_table(files["tactile_table"])
    refit = load_points(files["tactile_points"])
    assert np.allclose(table.a_kpa_per_count, refit.a_kpa_per_count, rtol=1e-9)
    counts = np.arange(0, TAXEL_COUNT_MAX, 97)
    for taxel in (0, 80, 161):
        kpa = table.a_kpa_per_count[taxel] * counts + table.b_kpa[taxel]
        back = (kpa - refit.b_kpa[taxel]) / refit.a_kpa_per_count[taxel]
        assert np.all(np.abs(back - counts) <= 1)


def _table(tmp_path: Path, body: str, header: str = "taxel,a_kpa_per_count,b_kpa") -> Path:
    path = tmp_path / "table.csv"
    path.write_text(f"# comment\n{header}\n{body}")
    return path


def _full_body(**replace: str) -> str:
    rows = {i: f"{i},0.0125,-6.0" for i in range(162)}
    rows.update({int(k[1:]): v for k, v in replace.items()})
    return "\n".join(rows.values()) + "\n"


@pytest.mark.parametrize(
    ("body", "header", "message"),
    [
        (_full_body(t5="5,abc,-6.0"), None, ":8: 'abc' is not a number"),
        (_full_body(t7="7,0.0125"), None, ":10: expected 3 fields, got 2"),
        (_full_body(t3="3,-0.01,0"), None, ":6: slope a must be > 0"),
        (_full_body(t9="400,0.0125,-6"), None, ":12: taxel 400 outside 0-161"),
        (_full_body(t9="8,0.0125,-6"), None, ":12: taxel 8 appears twice"),
        (_full_body(t2="2,nan,-6"), None, ":5: 'nan' is not finite"),
        (_full_body(), "taxel,gain,offset", ":2: expected the header"),
        ("", "", "empty calibration file"),
    ],
)
def test_a_corrupt_table_names_the_file_and_the_line(tmp_path: Path, body, header, message):
    path = _table(tmp_path, body, header if header is not None else "taxel,a_kpa_per_count,b_kpa")
    with pytest.raises(CalibrationFileError) as err:
        load_table(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_missing_files_and_taxels_are_named(tmp_path: Path):
    with pytest.raises(CalibrationFileError, match="no such calibration file"):
        load_table(tmp_path / "nope.csv")
    body = "\n".join(f"{i},0.0125,-6.0" for i in range(160)) + "\n"
    with pytest.raises(CalibrationFileError, match=r"no line for taxel.*160, 161"):
        load_table(_table(tmp_path, body))
    points = tmp_path / "points.csv"
    write_points([0, 0], [0.0, 100.0], [500, 8500], points)
    with pytest.raises(CalibrationFileError, match="taxel 1 has 0 calibration points"):
        load_points(points)


def test_eq6_sums_pressure_times_area_over_active_taxels():
    pressure = np.zeros(162)
    tip = LAYOUT.taxels_of("f2_tip")
    pressure[tip[:4]] = 50.0  # kPa on four 36 mm^2 cells
    pressure[tip[4]] = 0.4  # below the contact threshold: not active
    forces = pad_forces_n(pressure)
    assert forces[LAYOUT.pad_names.index("f2_tip")] == pytest.approx(4 * 50e3 * 36e-6)
    assert forces.sum() == pytest.approx(7.2)


def test_table_writes_enough_digits(tmp_path: Path):
    a = np.full(162, 0.0123456789123)
    cal = TaxelCalibration(a, np.full(162, -5.5))
    back = load_table(write_table(cal, tmp_path / "t.csv"))
    assert np.allclose(back.a_kpa_per_count, a, rtol=1e-9)
