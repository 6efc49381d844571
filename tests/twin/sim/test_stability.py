"""A twin too stiff or too damped for its step (issue 18): MuJoCo resets the diverged state and puts the
time back; the world says so in one line instead of stepping forever, and runs and fit replays end.

Each diverging case runs in a child process: before the fix it stepped forever at 100 % CPU, and a
child can be killed (the hang guard) where a thread cannot."""

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from twin.sim.backend import SimBackend
from twin.sim.foam import get_object

HANG_GUARD_S = 120


def _outcome(code: str, cwd: Path) -> dict:
    """Run `code` (which sets `job`, a callable) in a child python; what it raised, as a dict."""
    script = textwrap.dedent(code) + textwrap.dedent(
        """
        import json
        try:
            job()
            print(json.dumps({"raised": None}))
        except Exception as exc:
            print(json.dumps({"raised": type(exc).__name__, "message": str(exc)}))
        """
    )
    try:
        done = subprocess.run(
            [sys.executable, "-c", script], cwd=cwd, capture_output=True, text=True, timeout=HANG_GUARD_S
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"still stepping after {HANG_GUARD_S} s: the diverged simulation never ends")
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_diverging_world_raises_with_the_instant_and_what_to_change(tmp_path: Path):
    out = _outcome(
        """
        from twin.sim.backend import SimBackend
        from twin.sim.foam import get_object

        backend = SimBackend(get_object("block").with_overrides(young_pa=1e30))
        backend.connect()
        job = lambda: backend.clock.advance_to(1.0)
        """,
        tmp_path,
    )
    assert out["raised"] == "SimulationUnstableError", out
    message = out["message"]
    assert message.startswith("the simulation diverged at t = ")
    assert "E = 1e+30 Pa" in message and "--young" in message and len(message.splitlines()) == 1


def test_a_library_object_steps_cleanly():
    backend = SimBackend(get_object("block"))
    backend.connect()
    backend.clock.advance_to(0.5)
    assert backend.world.time_s == pytest.approx(0.5, abs=backend.world.timestep_s)
    assert backend.world.warnings() == {}


@pytest.mark.slow
@pytest.mark.parametrize("override", ["young_pa=1e30", "damping=1e20"])
def test_a_run_on_a_diverging_object_ends_failed_with_one_line(tmp_path: Path, override: str):
    """Once an endless loop at 100 % CPU (`twin run compress --young 1e308`; the CLI now refuses such
    flags, a script can still ask): the run ends, marked failed with the same one line."""
    out = _outcome(
        f"""
        from twin.experiments.compress import run_compress
        from twin.sim.backend import SimBackend
        from twin.sim.foam import get_object

        backend = SimBackend(get_object("block").with_overrides({override}))
        job = lambda: run_compress(backend, "x", duration_s=2.0, object_name="block")
        """,
        tmp_path,
    )
    assert out["raised"] == "SimulationUnstableError", out
    assert len(out["message"].splitlines()) == 1
    info = json.loads((tmp_path / "x" / "run.json").read_text())
    assert info["status"] == "failed" and info["error"].startswith(out["message"])
    assert info["metadata"]["stop"]["error_type"] == "SimulationUnstableError"


def test_a_fit_replay_of_a_diverging_foam_raises(tmp_path: Path):
    out = _outcome(
        """
        import numpy as np
        from twin.sim.foam import get_object
        from twin.sim.replay import Commands, replay

        t = np.arange(0, 1.0, 1 / 30)
        closing = np.tile([8000.0, 8000.0, 8000.0, 0.0], (len(t), 1))
        velocity = np.full(len(t), 12000.0)
        commands = Commands(t_s=t, position_counts=closing, max_velocity_counts_s=velocity, sample_t_s=t)
        job = lambda: replay(get_object("block").with_overrides(young_pa=1e30), commands)
        """,
        tmp_path,
    )
    assert out["raised"] == "SimulationUnstableError" and "diverged" in out["message"], out
