"""Session fixtures made once for the whole `pytest -n 2` run, not once per xdist worker."""

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from filelock import FileLock


def made_once(tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], object]) -> Path:
    """`make(path)` run once per test session, whichever xdist worker asks first; the others wait on its
    lock and read what it wrote (xdist's documented pattern, in the session's shared base directory).

    The suite's costliest fixtures (the sphere's 14 s run and its identification) would otherwise run on
    both workers at once: each xdist worker holds a session of its own, and the xdist_group marks that
    could keep their tests on one worker are ignored on pytest 9.2 (pyproject.toml's addopts)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # popen-gwN's parent: the session's own directory, one per `pytest` call
    path, done = root / name, root / f"{name}.done"
    with FileLock(root / f"{name}.lock"):
        if not done.exists():  # a worker whose make() raised left no mark: the next one tries again
            shutil.rmtree(path, ignore_errors=True)
            make(path)
            done.touch()
    return path
