"""Where the hand's MJCF is, in a checkout and in an installed wheel.

The repository keeps the model at models/barrett_mjcf/ (Menagerie layout); the wheel installs it as package
data of twin, at twin/models/barrett_mjcf/ (pyproject.toml's package-dir mapping). An editable install
(`pip install -e .`) leaves it where the checkout has it. `importlib.resources` on the mapped package does
not serve both: setuptools' editable finder does not find a data-only package nested in a regular one
(`twin.models` is no package in the checkout), so the folder is looked up beside the installed files first,
then in the checkout.
"""

from __future__ import annotations

from pathlib import Path

_TWIN_DIR = Path(__file__).resolve().parent


def _model_dir() -> Path:
    installed = _TWIN_DIR / "models" / "barrett_mjcf"  # a wheel: package data of twin
    checkout = _TWIN_DIR.parent / "models" / "barrett_mjcf"  # the repository (editable install, PYTHONPATH)
    return installed if installed.is_dir() else checkout


MODEL_DIR = _model_dir()
"""The hand's MJCF folder (bh8.xml, scene.xml, README.md, LICENSE, CHANGELOG.md)."""
HAND_XML = MODEL_DIR / "bh8.xml"
SCENE_XML = MODEL_DIR / "scene.xml"
