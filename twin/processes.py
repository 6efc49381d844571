"""Process lifecycle: SIGTERM as an interruption, and worker pools that never outlive their parent.

`sigterm_as_interrupt()` makes `kill PID` (a batch system, `timeout`, systemd) end a command exactly
as Ctrl-C does: KeyboardInterrupt in the main thread, so runs are marked "interrupted" and the hand is
idled. `worker_pool()` is a spawn-context ProcessPoolExecutor whose workers die with the parent
(Linux: PR_SET_PDEATHSIG = SIGKILL, set by each worker at start; elsewhere the parent's own cleanup),
leave Ctrl-C to the parent, and are terminated, queued work cancelled, when the parent's `with` block
ends in an error or an interruption: a killed or interrupted `twin fit` / `twin sweep` leaves no
worker behind holding memory and the terminal.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import pickle
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from types import FrameType
from typing import Any

from twin.interface.errors import WorkerLostError

PR_SET_PDEATHSIG = 1
"""prctl option (linux/prctl.h): the signal this process gets when its parent thread dies."""
TERMINATE_GRACE_S = 2.0
"""How long terminated workers get to exit before they are killed."""


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    """SIGTERM handler: the same KeyboardInterrupt a Ctrl-C raises."""
    raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


def sigterm_as_interrupt() -> bool:
    """Treat SIGTERM like Ctrl-C (KeyboardInterrupt in the main thread); idempotent.

    Returns False where no handler can be installed (not the main thread, or no SIGTERM here)."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "SIGTERM"):
        return False
    if signal.getsignal(signal.SIGTERM) is not _raise_interrupt:
        signal.signal(signal.SIGTERM, _raise_interrupt)
    return True


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """SIGINT and SIGTERM held back for the block, delivered when it ends: what must not be cut in half by
    a second Ctrl-C (a run's final status, the hand's idle) finishes first. Python runs signal handlers in
    the main thread, so the block swaps in a handler that only notes the signal and raises it again
    after. (Blocking them in the main thread's mask does not hold: the kernel then hands a signal to any
    other thread, Rerun's or a driver's, and Python still raises it in the main thread, inside the
    block.) Elsewhere than the main thread this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(ValueError, OSError):
            previous[sig] = signal.signal(sig, lambda signum, _frame: held.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        if held:
            signal.raise_signal(held[0])  # to the handler that was there: a KeyboardInterrupt now


def die_with_parent() -> None:
    """Ask the kernel to SIGKILL this process when its parent dies (Linux; a no-op elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)


def _start_worker(parent_pid: int, initializer: Callable[..., None] | None, initargs: tuple) -> None:
    """Every pool worker's first act: die with the parent, leave Ctrl-C to it, then the caller's setup."""
    die_with_parent()
    if os.getppid() != parent_pid:  # the parent died before the death signal was armed
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and ends the pool
    if initializer is not None:
        initializer(*initargs)


def stop_workers(pool: ProcessPoolExecutor) -> None:
    """Cancel queued work and end the pool's processes now (SIGTERM, then SIGKILL after a grace), then
    wait (bounded) for the pool's manager thread to finish with them.

    The manager thread reaps the workers and closes its wake-up pipe. Left running, it races two readers:
    a waitpid of ours gets ECHILD, which multiprocessing reads as "no exit status yet" (beside 4 hogs 1
    run of 30 read the statuses -15 and None); and at exit Python 3.11's concurrent.futures writes to
    that pipe as the thread closes it, a "Bad file descriptor" traceback after `twin fit` was stopped
    (once in a suite run, 2026-11-28)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown() forgets it
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(Exception):
            process.terminate()
    for process in processes:
        with contextlib.suppress(Exception):
            process.join(TERMINATE_GRACE_S)
            if process.is_alive():
                process.kill()
                process.join(TERMINATE_GRACE_S)
    if manager is not None:
        manager.join(2 * TERMINATE_GRACE_S)


_MAIN_GUARD_HINT = (
    "; from a script, start twin's worker processes (estimate_modulus, fit_run, ...) under "
    '`if __name__ == "__main__":`: each spawned worker runs the script\'s top level again'
)


def _failed_exit_status(processes: list[multiprocessing.process.BaseProcess]) -> int | None:
    """The exit status of a pool worker that ended by an error of its own (a positive status: a Python
    exception as it started, e.g. a script without a main guard), or None where none did (a kill).
    Read once the workers are joined (stop_workers): the pool breaks when a worker's pipe closes, which
    can be before its exit status can be read (seen on a loaded machine: None, then 1)."""
    for process in processes:
        if process.exitcode is not None and process.exitcode > 0:
            return int(process.exitcode)
    return None


@contextlib.contextmanager
def worker_pool(
    workers: int, initializer: Callable[..., None] | None = None, initargs: tuple[Any, ...] = ()
) -> Iterator[ProcessPoolExecutor]:
    """A spawn-context process pool whose workers die with this process and end with the block.

    Spawned, not forked: a caller that has rendered holds an EGL context a forked child would inherit.
    A normal exit waits for the work submitted; an exception or KeyboardInterrupt cancels what is
    queued and terminates the workers before it propagates."""
    pool = ProcessPoolExecutor(
        workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_start_worker,
        initargs=(os.getpid(), initializer, tuple(initargs)),
    )
    try:
        yield pool
    except BrokenProcessPool as exc:  # a worker killed (the OOM killer, `kill -9`): one line, not a traceback
        processes = list((getattr(pool, "_processes", None) or {}).values())
        stop_workers(pool)  # terminated, joined and reaped by the manager: every exit status is final
        failed = _failed_exit_status(processes)
        if failed is not None:  # an error at the worker's start, printed by it above: not a kill
            raise WorkerLostError(
                f"a worker process failed as it started (exit status {failed}; its error is printed above)"
                + _MAIN_GUARD_HINT
            ) from exc
        raise WorkerLostError(
            "a worker process ended abruptly (killed, or out of memory): run the command again, "
            "with fewer --workers if memory is short"
        ) from exc
    except BaseException:
        stop_workers(pool)
        raise
    pool.shutdown(wait=True)


KILL_GRACE_S = 2.0
"""How long a killed worker is waited for to be reaped (SIGKILL is not delayed by the work it does)."""


def run_killable(fn: Callable[..., Any], *args: Any, started: Callable[[], None] | None = None) -> Any:
    """fn(*args) in a child Python process that this one kills (SIGKILL) the moment it is interrupted.

    For C code that never returns to Python while it works (gmsh's meshing, a quadric decimation): in
    this process a Ctrl-C or SIGTERM would wait for it, minutes on a hostile input. Here the parent
    waits on a pipe, so KeyboardInterrupt (Ctrl-C, or SIGTERM via sigterm_as_interrupt) is raised at
    once; the child is then killed and reaped before it propagates, and dies with the parent if that is
    killed outright (PR_SET_PDEATHSIG). The child is `python -m twin.processes`, not a multiprocessing
    spawn, which would re-run a caller's script that lacks an `if __name__ == "__main__"` guard; it runs
    in a session of its own, so a terminal's Ctrl-C reaches only the parent, which ends it. fn and args
    must pickle (fn a module-level function); fn's exception is raised here as it was; what fn prints
    goes to stderr. `started` is called once the child exists (a progress line: from then on an
    interruption finds it and kills it)."""
    payload = pickle.dumps((os.getpid(), fn, args), protocol=pickle.HIGHEST_PROTOCOL)
    child = subprocess.Popen(
        [sys.executable, "-m", "twin.processes"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        assert child.stdin is not None and child.stdout is not None
        if started is not None:
            started()
        try:
            child.stdin.write(payload)
            child.stdin.close()
        except BrokenPipeError:  # the child died at once: its status says so below
            pass
        reply = child.stdout.read()
        child.wait()
    finally:
        if child.returncode is None:
            with contextlib.suppress(OSError):
                child.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.wait(KILL_GRACE_S)
        for stream in (child.stdin, child.stdout):
            with contextlib.suppress(OSError, AttributeError):
                stream.close()  # type: ignore[union-attr]
    if child.returncode != 0 or not reply:
        raise WorkerLostError(
            f"the worker process running {fn.__name__} ended abruptly (exit status {child.returncode}: "
            "killed, or out of memory)"
        )
    ok, value = pickle.loads(reply)  # this process's own child, over its own pipe
    if not ok:
        raise value
    return value


def _killable_child() -> None:
    """`python -m twin.processes`: run_killable's child. Reads (parent pid, fn, args) pickled on stdin,
    writes (ok, result or exception) pickled on stdout; anything fn prints goes to stderr."""
    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and kills this process
    reply = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # stdout (Python's and C's) to stderr: only the reply goes down the pipe
    sys.stdout = sys.stderr
    parent_pid, fn, args = pickle.load(sys.stdin.buffer)  # written by the parent
    if os.getppid() != parent_pid:  # the parent died before the death signal was armed
        os._exit(1)
    try:
        result = (True, fn(*args))
    except BaseException as exc:  # handed to the parent, which raises it
        result = (False, exc)
    try:
        data = pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception as exc:  # an unpicklable result or exception: its words still reach the parent
        data = pickle.dumps((False, RuntimeError(f"{type(result[1]).__name__}: {result[1]} ({exc})")))
    reply.write(data)
    reply.close()


if __name__ == "__main__":
    _killable_child()
