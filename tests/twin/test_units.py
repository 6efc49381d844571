"""Datasheet ratios of the conversion module (paper eqs. 1-3, §3.1)."""

import math

import numpy as np
import pytest

from twin import units


def test_full_finger_travel_is_140_degrees():
    assert math.degrees(units.finger_counts_to_inner_rad(17_000)) == pytest.approx(140.0)
    assert units.inner_rad_to_finger_counts(math.radians(70)) == pytest.approx(8_500)


def test_spread_travel_is_180_degrees():
    assert units.spread_counts_to_rad(3_140) == pytest.approx(math.pi)


def test_eq2_and_its_inverse():
    sg = np.arange(0, 256)
    assert units.torque_nm_to_strain(units.strain_to_torque_nm(sg)) == pytest.approx(sg)
    assert units.strain_to_torque_nm(0) == pytest.approx(-1.1675)
    assert units.strain_to_torque_nm(255) == pytest.approx(1.0, abs=1e-3)


def test_no_load_reading_and_eq3_disagreement_are_as_documented():
    assert units.NO_LOAD_STRAIN == pytest.approx(137.35, abs=0.01)
    # Eq. 3 reads 0.082 kg at eq. 2's zero; eq. 3's own zero is at 132.4 counts.
    assert units.strain_to_force_kg(units.NO_LOAD_STRAIN) == pytest.approx(0.082, abs=1e-3)
    assert -units.SG_FORCE_OFFSET_KG / units.SG_FORCE_SLOPE_KG == pytest.approx(132.4, abs=0.1)


def test_two_kg_at_the_fingertip_is_about_full_scale():
    torque = units.FINGERTIP_FORCE_LIMIT_KG * units.GRAVITY_M_S2 * units.FINGERTIP_MOMENT_ARM_M
    # Eq. 2 and eq. 3 agree near full scale: 2 kg at 50 mm is ~252 counts both ways.
    assert units.torque_nm_to_strain(torque) == pytest.approx(252.8, abs=0.5)
    assert (2.0 - units.SG_FORCE_OFFSET_KG) / units.SG_FORCE_SLOPE_KG == pytest.approx(252.2, abs=0.5)


def test_velocity_round_trip():
    rate = np.array([0.1, -2.0, 1.5])
    counts = units.drive_rad_s_to_velocity_counts(rate)
    assert units.velocity_counts_to_rad_s(counts) == pytest.approx(rate)
