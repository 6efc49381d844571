"""The benchmarks that drive `twin emulate rig` (camera_bridge, identification_hardware) never leave it
running: one that ignores Ctrl-C (as a child of a script's background job does) is killed after the grace
period, and the benchmark says so."""

import signal
import subprocess
import sys

from benchmarks.emulated_rig import stop as _stop


def test_an_emulator_that_ignores_ctrl_c_is_killed_after_the_grace(capsys):
    ignores = (
        "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print('up', flush=True); "
        "time.sleep(600)"
    )
    proc = subprocess.Popen([sys.executable, "-c", ignores], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "up"  # its handler is set before the Ctrl-C
    _stop(proc, grace_s=0.5)
    assert proc.returncode == -signal.SIGKILL
    assert "outlived its Ctrl-C by 0.5 s and was killed" in capsys.readouterr().err


def test_an_emulator_that_stops_on_ctrl_c_is_only_asked():
    proc = subprocess.Popen([sys.executable, "-c", "import time; print('up', flush=True); time.sleep(600)"],
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert proc.stdout.readline().strip() == "up"
    _stop(proc, grace_s=30)
    assert proc.returncode == -signal.SIGINT  # ended by the Ctrl-C itself (Python re-raises it), not killed
