"""Identification of eq. 4 from recorded runs: the hand's own dynamics from a free-motion run, each
finger's object reaction model R(delta, delta_dot), and the foam's Young's modulus through a mapping
built on the twin. Reads recordings only (never a backend), so hardware runs go through unchanged."""
