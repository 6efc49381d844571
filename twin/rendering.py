"""The OpenGL back-end of twin's own renders (the cameras, the surface truth), chosen when it renders.

MuJoCo reads MUJOCO_GL once, when it is first imported, and builds every `mujoco.Renderer` on that
choice: a script that imported mujoco before twin (MUJOCO_GL unset) got GLFW, which needs a display,
and its first camera frame died with `gladLoadGL error`. `renderer()` builds twin's renderers on the
back-end MUJOCO_GL names when they are made (EGL unless it names another), whatever mujoco chose at
its import, so the import order does not matter. It also lets the `twin` command import MuJoCo with
its default context off (`disable_default_context`): a run without cameras then loads neither
PyOpenGL nor an EGL display.
"""

from __future__ import annotations

import importlib
import os
import sys
import threading
from typing import TYPE_CHECKING

from twin.interface.errors import ConfigError

if TYPE_CHECKING:
    import mujoco

CHOSEN_BY_USER = os.environ.get("MUJOCO_GL")
"""MUJOCO_GL as the process had it before twin was imported (None: unset, twin's default applies)."""

DEFAULT = "egl"
"""twin's back-end where MUJOCO_GL names none: EGL renders offscreen, headless, no display needed."""

_MODULES = {"egl": "mujoco.egl", "osmesa": "mujoco.osmesa", "glx": "mujoco.glfw", "glfw": "mujoco.glfw"}
"""MUJOCO_GL's back-end names on Linux and the mujoco module holding each one's GLContext."""
_GLFW_ALIASES = ("enable", "enabled", "on", "true", "1")
"""MuJoCo's own words for "its default back-end" (GLFW)."""
_OFF = ("", "disable", "disabled", "off", "false", "0")
"""MUJOCO_GL values that leave MuJoCo's default context off: twin still renders, on DEFAULT."""

_SWAP = threading.Lock()


def gl_backend() -> str:
    """The back-end twin renders with now: MUJOCO_GL's when it names one, else DEFAULT (egl)."""
    value = os.environ.get("MUJOCO_GL", "").strip().lower()
    if value in _OFF:
        return DEFAULT
    if value in _GLFW_ALIASES:
        return "glfw"
    if value not in _MODULES:
        raise ConfigError(f"MUJOCO_GL={value}: not a rendering back-end; set egl, osmesa or glx, or unset it")
    return value


def disable_default_context() -> None:
    """For a process that renders only through `renderer()` (the `twin` command): MuJoCo, when it is
    imported, builds no default context, so a run without cameras loads no OpenGL. Does nothing when
    the user chose MUJOCO_GL or mujoco is already imported."""
    if CHOSEN_BY_USER is None and "mujoco" not in sys.modules:
        os.environ["MUJOCO_GL"] = "disable"


def renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A `mujoco.Renderer` on gl_backend()'s context (a one-line ConfigError where it cannot load)."""
    import mujoco
    from mujoco.rendering.classic import gl_context

    name = gl_backend()
    try:
        wanted = importlib.import_module(_MODULES[name]).GLContext
    except (ImportError, AttributeError) as exc:  # e.g. PyOpenGL already set up for another platform
        raise ConfigError(
            f"cannot render through {name} (MUJOCO_GL): {' '.join(str(exc).split())}; set MUJOCO_GL to a "
            "back-end this machine has (egl, osmesa or glx) before starting Python"
        ) from None
    missing = object()
    current = getattr(gl_context, "GLContext", missing)
    if current is wanted:
        return mujoco.Renderer(model, height=height, width=width)
    # mujoco.Renderer takes its context class from this module global when it is built: lend it
    # ours for the one construction (under a lock: the cameras build theirs on a render thread).
    with _SWAP:
        gl_context.GLContext = wanted
        try:
            return mujoco.Renderer(model, height=height, width=width)
        finally:
            if current is missing:
                del gl_context.GLContext
            else:
                gl_context.GLContext = current
