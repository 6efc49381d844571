"""Shared settings: headless MuJoCo for every test, and one OpenMP thread per test process.

The suite runs as `pytest -n 2` on a 2-core machine: each worker has a core. A second torch thread in
one worker spins against the other worker (and against notebook kernels and sweep workers, which
inherit this environment): 300 full-batch epochs of the shape network on 9600 samples took 2.0 s on
one thread and 6.8-9.8 s on two with another process busy.

Ctrl-C reaches the `twin` processes the tests start even when the suite itself was started with SIGINT
ignored (a background job of a non-interactive shell): their Ctrl-C tests would otherwise run to the
end and exit 0."""

import os
import signal

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")

if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)  # children start with the default again
