"""Tactile pads: their layout (ids, positions, areas) and calibration (eqs. 5 and 6).

Backend-free: the same code converts sim and hardware readings.
"""
