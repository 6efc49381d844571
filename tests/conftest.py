"""Shared settings: headless MuJoCo for every test, one OpenMP thread per test process, and a foam
calibration cache of the suite's own.

The suite runs as `pytest -n 2` on a 2-core machine: each worker has a core. A second torch thread in
one worker spins against the other worker (and against notebook kernels and sweep workers, which
inherit this environment): 300 full-batch epochs of the shape network on 9600 samples took 2.0 s on
one thread and 6.8-9.8 s on two with another process busy.

Ctrl-C reaches the `twin` processes the tests start even when the suite itself was started with SIGINT
ignored (a background job of a non-interactive shell): their Ctrl-C tests would otherwise run to the
end and exit 0."""

import os
import signal

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")
_USER_CACHE = "TWIN_CACHE_DIR" in os.environ


@pytest.fixture(scope="session", autouse=True)
def _calibration_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """First-use foam calibrations (twin.sim.calibration) go to a cache of this `pytest` call's own, shared
    by its xdist workers and the processes they start: never the user's ~/.cache, and never a cache an
    earlier run left, so every run pays what a fresh machine pays (a TWIN_CACHE_DIR set by the caller is
    kept)."""
    if _USER_CACHE:
        return
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # popen-gwN's parent: the session's own directory (tests/once.py)
    os.environ["TWIN_CACHE_DIR"] = str(root / "calibration-cache")


if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)  # children start with the default again
