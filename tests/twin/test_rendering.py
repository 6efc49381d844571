"""twin's renders choose their OpenGL back-end when they are made (twin.rendering), so the order in
which a script imports mujoco and twin does not matter. Each case runs in a fresh interpreter, since
MuJoCo reads MUJOCO_GL once, at its first import; DISPLAY is removed, as on a headless machine."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from twin.interface.errors import ConfigError
from twin.rendering import gl_backend


def _python(code: str, cwd: Path, **env: str) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY")}
    return subprocess.run(
        [sys.executable, "-c", code],
        cwd=cwd,
        env={**base, **env},
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_a_script_that_imports_mujoco_before_twin_runs_the_cameras(tmp_path: Path):
    # MUJOCO_GL unset when mujoco is imported: MuJoCo picks GLFW, which needs a display. Before
    # twin.rendering this camera run died at its first frame with `gladLoadGL error`.
    code = (
        "import mujoco\n"
        "from mujoco.rendering.classic import gl_context\n"
        "assert gl_context.GLContext.__module__ == 'mujoco.glfw', gl_context.GLContext\n"
        "import twin\n"
        "out = twin.compress(twin.sim_backend('block', cameras=True), duration_s=0.1, out='run', "
        "progress=None)\n"
        "run = twin.open_run(out.run_dir)\n"
        "print(out.status, len(run.stream('stereo')), gl_context.GLContext.__module__)"
    )
    result = _python(code, tmp_path)
    assert result.returncode == 0, result.stderr
    status, frames, default_context = result.stdout.split()
    assert status == "complete" and int(frames) >= 3
    assert default_context == "mujoco.glfw"  # MuJoCo's own default is left as the script had it


def test_twin_renders_with_mujocos_default_context_off(tmp_path: Path):
    # What the `twin` command does (rendering.disable_default_context): MuJoCo imported with no
    # context of its own, so only twin's renderer builds one, on EGL.
    code = (
        "import mujoco, numpy as np\n"
        "from mujoco.rendering.classic import gl_context\n"
        "from twin.rendering import renderer\n"
        'm = mujoco.MjModel.from_xml_string(\'<mujoco><worldbody><light pos="0 0 2"/>'
        '<geom type="box" size=".1 .1 .1" rgba="1 0 0 1"/></worldbody></mujoco>\')\n'
        "d = mujoco.MjData(m); mujoco.mj_forward(m, d)\n"
        "r = renderer(m, 24, 32); r.update_scene(d); image = r.render(); r.close()\n"
        "red, green = int(image[..., 0].max()), int(image[..., 1].max())\n"
        "print(*image.shape, red, green, hasattr(gl_context, 'GLContext'))"
    )
    result = _python(code, tmp_path, MUJOCO_GL="disable")
    assert result.returncode == 0, result.stderr
    h, w, channels, red, green, default_context = result.stdout.split()
    assert (int(h), int(w), int(channels)) == (24, 32, 3)
    assert int(red) > 100 > int(green)  # the red box was drawn
    assert default_context == "False"  # MuJoCo's own default context is still off


@pytest.mark.parametrize(
    ("value", "backend"),
    [(None, "egl"), ("disable", "egl"), ("EGL", "egl"), ("osmesa", "osmesa"), ("1", "glfw")],
)
def test_gl_backend_follows_mujoco_gl(monkeypatch: pytest.MonkeyPatch, value: str | None, backend: str):
    if value is None:
        monkeypatch.delenv("MUJOCO_GL", raising=False)
    else:
        monkeypatch.setenv("MUJOCO_GL", value)
    assert gl_backend() == backend


def test_an_unknown_mujoco_gl_is_one_line(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("MUJOCO_GL", "vulkan")
    with pytest.raises(
        ConfigError, match=r"^MUJOCO_GL=vulkan: not a rendering back-end; set egl, osmesa or glx"
    ):
        gl_backend()
