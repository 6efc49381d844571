"""A run that completed, but not as declared, tells a Python caller with `warnings.warn` (a RunWarning at
the caller's line), and the `twin` command prints each such warning once, as its own one line."""

import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

import twin
from twin import HandReading


def _slow(reading: HandReading) -> None:
    """60 ms a reading: a 30 Hz hand loop cannot keep its rate (keeps the hand's last command)."""
    time.sleep(0.06)


def test_a_hardware_loop_below_its_rate_warns_the_caller(tmp_path: Path):
    with pytest.warns(twin.RunWarning) as caught:
        outcome = twin.run(
            twin.hardware_backend(hand="bh8emu://?object=block"), _slow, duration_s=1, out=tmp_path
        )
    assert outcome.status == "complete"
    (warning,) = caught
    assert str(warning.message).startswith("hand loop ran at ") and "of 30 Hz" in str(warning.message)
    assert [str(warning.message)] == outcome.warnings == twin.open_run(tmp_path).warnings
    assert warning.filename == __file__  # points at the caller's line, not into twin
    # and in the viewer's log, as a warning row at the run's end, after the row where the loop first
    # fell over a period behind its schedule (the events' hand_loop lane starts there)
    import rerun as rr

    from twin.viz.rerun_log import _rows

    text, level = rr.TextLog.descriptor_text().component, rr.TextLog.descriptor_level().component
    rows = _rows(tmp_path / "run.rrd", "log", [text, level])
    warned = [c[text][0] for _, c in rows if c[level] == ["WARN"]]
    assert warned[-1] == str(warning.message)
    assert warned[:-1] and all(" behind its 30 Hz schedule: readings are late" in w for w in warned[:-1])


def test_a_run_as_declared_warns_nothing(tmp_path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("error", twin.RunWarning)
        outcome = twin.compress(twin.sim_backend("block"), duration_s=0.2, out=tmp_path)
    assert outcome.status == "complete" and outcome.warnings == []


@pytest.mark.slow
def test_the_cli_prints_a_recovered_cycle_once_and_no_python_warning(tmp_path: Path):
    # drop@31: the emulator swallows one reply and the driver recovers the cycle (a RunWarning from the
    # API, which the command prints as its own line instead of Python's warning text).
    argv = [
        "run",
        "compress",
        "--backend",
        "hardware",
        "--hand",
        "bh8emu://?faults=drop@31",
        "--duration",
        "2",
    ]
    result = subprocess.run(
        [sys.executable, "-m", "twin", *argv, "--out", str(tmp_path / "hw"), "--no-progress"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONWARNINGS": "default"},
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    lines = result.stderr.splitlines()
    recovered = [line for line in lines if line.startswith("twin: warning: the hand driver recovered")]
    assert len(recovered) == 1 and "recovered 1 cycle(s)" in recovered[0], lines
    # Every line is the command's own (no Python warning text). On a busy machine the loop-rate warning may
    # join it, truthfully: a 2 s run has 40 ms of slack before 98 % (beside the suite one took 2.16 s).
    assert all(line.startswith("twin: warning: ") for line in lines), lines
    assert len(lines) == 1 or (len(lines) == 2 and any("hand loop ran at" in line for line in lines)), lines
    import rerun as rr  # the viewer's log says it too

    from twin.viz.rerun_log import _rows

    text, level = rr.TextLog.descriptor_text().component, rr.TextLog.descriptor_level().component
    rows = _rows(tmp_path / "hw" / "run.rrd", "log", [text, level])
    warned = [c[text][0] for _, c in rows if c[level] == ["WARN"]]
    assert any(w.startswith("the hand driver recovered 1 cycle(s)") for w in warned), warned
