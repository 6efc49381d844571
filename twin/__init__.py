"""barrett-twin: a MuJoCo digital twin and hardware bridge of a Barrett BH8 hand squeezing foam.

The public API (docs/api.md) is importable from here: `twin.sim_backend`, `twin.hardware_backend`,
`twin.run`, `twin.compress`, `twin.open_run`, ... Those names load on first use (twin.api), so
`import twin` stays light for the modules that only need `twin.units`.
"""

import os
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from twin import rendering as _rendering  # notes the caller's MUJOCO_GL before the default below

# MuJoCo reads MUJOCO_GL once, when it is first imported, for its default context: headless (EGL) by
# default for a caller's own mujoco.Renderer; a caller's own choice is kept. twin's renders choose their
# back-end when they are made (twin.rendering), whichever of mujoco and twin was imported first.
os.environ.setdefault("MUJOCO_GL", _rendering.DEFAULT)

try:
    __version__ = version("barrett-twin")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0+unknown"

_API = (
    "Backend",
    "ControllerFn",
    "HandCommand",
    "HandReading",
    "Run",
    "RunOutcome",
    "RunWarning",
    "SafetyLimits",
    "compress",
    "foam",
    "free",
    "hardware_backend",
    "library",
    "load_shape_model",
    "open_run",
    "run",
    "sim_backend",
)
__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    """twin.api's names, imported on first use."""
    if name in _API:
        from twin import api

        return getattr(api, name)
    raise AttributeError(f"module 'twin' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
