"""The child processes of a process, read from Linux's /proc: for tests that check a command leaves no
worker behind."""

from pathlib import Path


def child_pids(pid: int) -> set[int]:
    """The processes whose parent is `pid` (each /proc/PID/stat's ppid; any of its threads' children)."""
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.add(int(entry.name))
    return found
