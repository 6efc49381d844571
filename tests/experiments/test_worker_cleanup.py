"""SIGTERM is Ctrl-C, and worker pools die with their parent (issue 18): `kill` of `twin fit --workers 2`
or `twin sweep --workers 2` leaves no worker process behind (they once lived 30+ minutes at ~250 MB
each, holding the terminal)."""

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from twin.experiments.compress import run_compress

from twin.processes import sigterm_as_interrupt
from twin.sim.backend import SimBackend
from twin.sim.foam import get_object


def child_pids(pid: int) -> list[int]:
    """The live child processes of `pid` (Linux /proc; empty elsewhere)."""
    children = []
    with contextlib.suppress(OSError):
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            with contextlib.suppress(OSError, ValueError, IndexError):
                with open(f"/proc/{entry}/stat", encoding="ascii", errors="replace") as f:
                    stat = f.read()
                fields = stat[stat.rindex(")") + 2 :].split()
                if int(fields[1]) == pid and fields[0] != "Z":
                    children.append(int(entry))
    return children


def descendant_pids(pid: int) -> list[int]:
    """Every live process below `pid` (children, their children, ...)."""
    out, todo = [], [pid]
    while todo:
        kids = child_pids(todo.pop())
        out += kids
        todo += kids
    return out


TWIN = [sys.executable, "-m", "twin.cli"]


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> Path:
    """A 6 s compress run on the twin: enough for a fit to start its replays."""
    path = tmp_path_factory.mktemp("fit") / "run"
    run_compress(SimBackend(get_object("block")), path, duration_s=6.0, object_name="block")
    return path


def _alive(pid: int) -> bool:
    """True while `pid` runs (a zombie waiting for its reaper has ended)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as f:
            stat = f.read()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _start_with_workers(args: list[str], cwd: Path, workers: int = 2) -> tuple[subprocess.Popen, list[int]]:
    """Start `twin ARGS` and wait (hang guard: 90 s) until its pool's worker processes exist."""
    proc = subprocess.Popen(
        [*TWIN, *args], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and proc.poll() is None:
        pids = descendant_pids(proc.pid)
        if sum("spawn_main" in _cmdline(p) for p in pids) >= workers:
            return proc, pids
        time.sleep(0.1)
    proc.kill()
    raise AssertionError(f"no {workers} workers appeared: {proc.communicate()}")


def _assert_all_gone(pids: list[int], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.1)
    left = [f"{p}: {_cmdline(p)}" for p in pids if _alive(p)]
    for p in pids:  # never leave them to the rest of the suite
        if _alive(p):
            os.kill(p, signal.SIGKILL)
    assert not left, left


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and the parent-death signal")
def test_sigterm_on_fit_interrupts_it_and_ends_its_workers(short_run: Path, tmp_path: Path):
    proc, pids = _start_with_workers(
        ["fit", str(short_run), "--workers", "2", "--out", str(tmp_path / "fit"), "--no-progress"], tmp_path
    )
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    _assert_all_gone(pids)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and the parent-death signal")
def test_sigkill_on_fit_takes_its_workers_with_it(short_run: Path, tmp_path: Path):
    proc, pids = _start_with_workers(
        ["fit", str(short_run), "--workers", "2", "--out", str(tmp_path / "fit"), "--no-progress"], tmp_path
    )
    proc.kill()
    proc.communicate(timeout=30)
    _assert_all_gone(pids)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and the parent-death signal")
def test_sigterm_on_sweep_interrupts_it_and_ends_its_workers(tmp_path: Path):
    args = ["sweep", "--objects", "block", "--trajectories", "4", "--workers", "2", "--duration", "8"]
    proc, pids = _start_with_workers([*args, "--out", "ds", "--no-progress"], tmp_path)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    _assert_all_gone(pids)


def test_sigterm_as_interrupt_raises_keyboard_interrupt_and_is_idempotent():
    previous = signal.getsignal(signal.SIGTERM)
    try:
        assert sigterm_as_interrupt() and sigterm_as_interrupt()
        handler = signal.getsignal(signal.SIGTERM)
        assert sigterm_as_interrupt() and signal.getsignal(signal.SIGTERM) is handler
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler runs between bytecodes: at once
    finally:
        signal.signal(signal.SIGTERM, previous)
