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
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")
# First-use foam calibrations (twin.sim.calibration) go to a cache of the suite's own, shared by its
# workers and the processes they start, never to the user's ~/.cache.
_CACHE = Path(tempfile.gettempdir()) / f"barrett-twin-tests-{os.getuid()}"
os.environ.setdefault("TWIN_CACHE_DIR", str(_CACHE))

if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)  # children start with the default again
