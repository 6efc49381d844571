"""Shared fixtures: headless MuJoCo for every test."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
