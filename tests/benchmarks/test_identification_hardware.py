"""The hardware identification benchmark puts in the emulated rig's hand exactly the foam the sim's hidden
case would hold: its flags, parsed by `twin emulate`'s own parser, make the same FoamParams."""

import dataclasses
from pathlib import Path

import pytest

from benchmarks import identification as hidden
from benchmarks.identification_hardware import DRAW_SEED, FIRST_NOISE_SEED, emulator_flags
from twin.cli import build_parser
from twin.cli.emulate import _foam_from_args

LABELS = ("name", "stiffness_class", "rgba")
"""What tells objects apart in a listing, not in the physics."""


@pytest.mark.parametrize("shape", hidden.SHAPES)
def test_the_emulator_holds_the_hidden_cases_foam(shape: str, tmp_path: Path):
    case = next(c for c in hidden.draw_cases(1, tmp_path, DRAW_SEED, FIRST_NOISE_SEED) if c["shape"] == shape)
    args = build_parser().parse_args(["emulate", "rig", *emulator_flags(case)])
    emulated, drawn = _foam_from_args(args), hidden._foam(case)
    physics = {f.name for f in dataclasses.fields(drawn)} - set(LABELS)
    for field in sorted(physics):
        got, want = getattr(emulated, field), getattr(drawn, field)
        same = got == pytest.approx(want, rel=1e-12) if isinstance(want, float | tuple) else got == want
        assert same, (field, got, want)
