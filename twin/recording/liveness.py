"""Whether the process writing a run still lives: run.json's `writer` record and the check on it.

A run whose writer was SIGKILLed (or whose machine lost power) keeps status "running" for ever. The
writer records its PID, host, boot id and process start time; a reader on the same host can then tell a
run still being written from a dead one (a PID reused by another process has another start time).
"""

from __future__ import annotations

import os
import socket
from pathlib import Path


def _read(path: str) -> str | None:
    try:
        return Path(path).read_text().strip()
    except OSError:
        return None


def _boot_id() -> str | None:
    return _read("/proc/sys/kernel/random/boot_id")


def _start_ticks(pid: int) -> int | None:
    """The process's start time (clock ticks since boot, /proc/PID/stat field 22), None if unknown."""
    stat = _read(f"/proc/{pid}/stat")
    if stat is None:
        return None
    try:
        return int(stat.rsplit(")", 1)[1].split()[19])
    except (IndexError, ValueError):
        return None


def writer_identity() -> dict:
    """This process, as run.json's `writer` records it."""
    pid = os.getpid()
    return {"pid": pid, "host": socket.gethostname(), "boot_id": _boot_id(), "start_ticks": _start_ticks(pid)}


def writer_alive(info: dict) -> bool | None:
    """For a run's run.json: True while its writer process lives, False once it is gone, None when this
    host cannot tell (another host, or a run written before writers were recorded)."""
    writer = info.get("writer") if isinstance(info, dict) else None
    if not isinstance(writer, dict) or writer.get("host") != socket.gethostname():
        return None
    pid = writer.get("pid")
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return None
    boot = _boot_id()
    if isinstance(writer.get("boot_id"), str) and boot is not None and writer["boot_id"] != boot:
        return False  # the machine restarted since
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # someone else's process: it exists
    except OverflowError:
        return None
    recorded, now = writer.get("start_ticks"), _start_ticks(pid)
    # a start time other than the recorded one: the PID now belongs to another process
    return not (isinstance(recorded, int) and now is not None and recorded != now)
