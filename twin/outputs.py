"""Where commands write: checked writable before any computation, and new directories created whole.

- `check_writable(path, flag)`: the nearest existing ancestor of `path` takes a file (a real probe: a
  temporary directory created and removed; `os.access` says yes to root on a read-only mount), so a
  read-only, full or forbidden place is refused in one line before minutes of computing.
- `new_directory(out, flag)`: a context manager yielding a private temporary directory beside `out`;
  on success it is renamed to `out` in one step (rename(2) replaces only a missing or empty directory),
  so two writers into one `out` cannot both succeed, and a failure (a full disk, Ctrl-C) leaves no
  half-written `out` behind.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from twin.interface.errors import ConfigError


def nearest_existing(path: Path) -> Path:
    """`path` itself if it exists, else its nearest existing ancestor."""
    here = path
    while not os.path.lexists(here) and here != here.parent:
        here = here.parent
    return here


def check_writable(path: Path, flag: str = "--out") -> None:
    """ConfigError (one line) unless something can be written where `path` is or would be created."""
    try:
        os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):
        pass
    except OSError as exc:  # a name too long, a loop of links: no use computing anything first
        raise ConfigError(f"{flag} {path}: {exc.strerror or exc}") from None
    except ValueError as exc:  # a NUL byte
        raise ConfigError(f"{flag} {path!r}: {exc}") from None
    where = nearest_existing(Path(path))
    if not where.is_dir():
        raise ConfigError(f"{flag} {path}: {where} is not a directory")
    try:
        tempfile.TemporaryDirectory(dir=where, prefix=".twin-probe-").cleanup()
    except OSError as exc:
        raise ConfigError(f"{flag} {path}: cannot write in {where} ({exc.strerror or exc})") from None


def check_new_directory(out: Path, flag: str = "--out") -> None:
    """ConfigError unless `out` is missing or an empty directory, in a place that can be written."""
    if os.path.lexists(out):
        if not out.is_dir() or out.is_symlink():
            raise ConfigError(f"{flag} {out}: exists and is not a directory")
        if any(out.iterdir()):
            raise ConfigError(f"{flag} {out}: exists and is not an empty directory; choose a new one")
    check_writable(out, flag)


@contextlib.contextmanager
def new_directory(out: Path, flag: str = "--out") -> Iterator[Path]:
    """A temporary directory to fill, renamed to `out` when the block ends without an error."""
    out = Path(out)
    check_new_directory(out, flag)
    parent = nearest_existing(out.parent)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name[:64]}.", suffix=".partial", dir=out.parent))
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        tmp.chmod(0o777 & ~umask)  # mkdtemp's 0700 was for while it was being written
        try:
            os.rename(tmp, out)
        except OSError as exc:
            if exc.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
                raise ConfigError(
                    f"{flag} {out}: written by someone else meanwhile (another export?); "
                    "nothing of this one was kept"
                ) from None
            raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if parent != out.parent and not os.path.lexists(out):
            _remove_empty_parents(out.parent, parent)


def _remove_empty_parents(path: Path, stop: Path) -> None:
    """Remove the directories this command created above `out` (empty ones, up to `stop`)."""
    here = path
    while here != stop and here != here.parent:
        try:
            here.rmdir()
        except OSError:
            return
        here = here.parent
