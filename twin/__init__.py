"""barrett-twin: a MuJoCo digital twin and hardware bridge of a Barrett BH8 hand squeezing foam."""

import os
from importlib.metadata import PackageNotFoundError, version

# Headless by default: MuJoCo reads MUJOCO_GL when it is first imported, and any twin module may be
# what imports it (the sim, the viewer, the hand's kinematics); a caller's own choice is kept.
os.environ.setdefault("MUJOCO_GL", "egl")

try:
    __version__ = version("barrett-twin")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0+unknown"
