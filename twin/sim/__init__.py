"""MuJoCo simulation backend. Headless by default: MUJOCO_GL=egl unless the caller chose one."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
