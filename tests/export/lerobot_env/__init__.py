"""The LeRobot side environment: a virtual environment with lerobot 0.4.4's own, unmodified code, in which
tests/export/test_export.py reads the exports with LeRobot's loader and dataset tools.

lerobot 0.4.4 pins torch<2.11 and rerun-sdk<0.27, which conflict with this project's torch 2.13.0 and
rerun-sdk 0.41, so it cannot share the project's environment. This one holds torch 2.13.0 (the CPU build)
and the dependencies lerobot's dataset, dataset-tool and policy-config modules import (requirements.txt,
every version pinned by constraints.txt), lerobot==0.4.4 installed with --no-deps, and the torchvision
stand-in (torchvision/: the only torchvision wheel for torch 2.13.0 on the registry is a CUDA build).

`lerobot_python()` builds it on first use into the user's cache (~/.cache/barrett-twin/lerobot-env/KEY,
KEY a hash of those files and the Python version, so a changed pin builds a new one), under a file lock
(the suite's xdist workers build it once), in a temporary directory renamed into place only when complete
and importable: a failed or interrupted build leaves nothing a later run trusts. $TWIN_LEROBOT_PYTHON,
where set, names the interpreter to use instead, and nothing is built. `python -m tests.export.lerobot_env`
builds it and prints its interpreter.

Each use stamps the environment (`.used`); an environment of another key left unused for PRUNE_AFTER_DAYS
is removed (1.5 GB each: a pin changed months ago would otherwise keep its old build for ever), unless
another process holds its lock."""

import contextlib
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from filelock import FileLock, Timeout

HERE = Path(__file__).resolve().parent
LEROBOT = "lerobot==0.4.4"
STAND_IN = HERE / "torchvision"
IMPORTS = (
    "import lerobot.datasets.lerobot_dataset, lerobot.datasets.dataset_tools, "
    "lerobot.policies.act.configuration_act"
)
"""What a built environment must import before it is moved into place."""
BUILD_TIMEOUT_S = 1800.0
"""How long a build (or a wait on another worker's) may take: ~130 MB of downloads and ~1.5 GB unpacked."""
PRUNE_AFTER_DAYS = 30.0
"""An environment of another key unused this long is removed when this one is used (another checkout that
still pins it builds it again on its first use: minutes, not lost data)."""


class BuildError(RuntimeError):
    """The side environment could not be built; the message is one line saying which step and why."""


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "barrett-twin" / "lerobot-env"


def key() -> str:
    """A hash of everything the environment is built from: its pins, the stand-in, the Python version."""
    digest = hashlib.sha256(f"{LEROBOT} python{sys.version_info[0]}.{sys.version_info[1]}".encode())
    files = [HERE / "requirements.txt", HERE / "constraints.txt", *sorted(STAND_IN.rglob("*.py"))]
    for path in files:
        digest.update(path.relative_to(HERE).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def interpreter(env: Path) -> Path:
    return env / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def lerobot_python() -> Path:
    """The interpreter of the side environment: $TWIN_LEROBOT_PYTHON (a path or a command on PATH), else
    the cached one, built (once, under a lock) if it is not there. Raises BuildError."""
    named = os.environ.get("TWIN_LEROBOT_PYTHON")
    if named:
        found = shutil.which(named)
        if found is None:
            raise BuildError(f"TWIN_LEROBOT_PYTHON names {named!r}: no such interpreter")
        return Path(found)
    root, name = cache_root(), key()
    env = root / name
    if env.is_dir():  # only a complete build is ever renamed to this name
        _stamp(env)
        prune_stale(root, keep=name)
        return interpreter(env)
    root.mkdir(parents=True, exist_ok=True)
    try:
        with FileLock(root / f"{name}.lock", timeout=BUILD_TIMEOUT_S):
            if not env.is_dir():  # another worker may have built it while this one waited
                for stale in root.glob(f"{name}.partial-*"):  # a build killed before it could clean up
                    shutil.rmtree(stale, ignore_errors=True)
                partial = Path(tempfile.mkdtemp(prefix=f"{name}.partial-", dir=root))
                try:
                    _build(partial, root / f"{name}.build.log")
                    partial.rename(env)
                finally:
                    shutil.rmtree(partial, ignore_errors=True)
    except Timeout:
        raise BuildError(f"waited {BUILD_TIMEOUT_S:.0f} s for another build of {env}") from None
    _stamp(env)
    prune_stale(root, keep=name)
    return interpreter(env)


def _stamp(env: Path) -> None:
    """Mark `env` as used now (what prune_stale reads); a read-only cache just goes unmarked."""
    with contextlib.suppress(OSError):
        (env / ".used").touch()


def prune_stale(root: Path, keep: str, older_than_days: float = PRUNE_AFTER_DAYS) -> list[Path]:
    """Remove the environments under `root` other than `keep` whose last use (their `.used` stamp, else the
    directory itself) is older than `older_than_days`, skipping any whose lock another process holds; the
    removed paths. Only names a build makes (16 hex digits) are touched."""
    removed = []
    cutoff = time.time() - older_than_days * 86400.0
    for env in sorted(root.iterdir()) if root.is_dir() else []:
        if env.name == keep or not env.is_dir() or not re.fullmatch(r"[0-9a-f]{16}", env.name):
            continue
        stamp = env / ".used"
        try:
            last_used = (stamp if stamp.exists() else env).stat().st_mtime
        except OSError:
            continue
        if last_used >= cutoff:
            continue
        try:
            with FileLock(root / f"{env.name}.lock", timeout=0):
                shutil.rmtree(env, ignore_errors=True)
                (root / f"{env.name}.build.log").unlink(missing_ok=True)
        except Timeout:  # in use by another process right now
            continue
        removed.append(env)
    return removed


def _build(env: Path, log: Path) -> None:
    python = str(interpreter(env))
    log.write_text("")
    _step("creating the virtual environment", [sys.executable, "-m", "venv", str(env)], log)
    pip = [python, "-m", "pip", "install", "--constraint", str(HERE / "constraints.txt")]
    _step("pip install -r requirements.txt", [*pip, "--requirement", str(HERE / "requirements.txt")], log)
    _step(f"pip install --no-deps {LEROBOT}", [*pip, "--no-deps", LEROBOT], log)
    where = "import sysconfig; print(sysconfig.get_path('purelib'))"
    purelib = Path(_step("locating site-packages", [python, "-c", where], log).strip())
    shutil.copytree(STAND_IN, purelib / "torchvision", ignore=shutil.ignore_patterns("__pycache__"))
    _step("importing lerobot", [python, "-c", IMPORTS], log)


def _step(what: str, argv: list[str], log: Path) -> str:
    """Run one build step, its output appended to `log`; its stdout, or BuildError naming the step, the
    first error it printed and the log."""
    done = subprocess.run(argv, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    with log.open("a") as out:
        out.write(f"$ {' '.join(argv)}\n{done.stdout}{done.stderr}\n")
    if done.returncode != 0:
        lines = [line.strip() for line in done.stderr.splitlines() if line.strip()]
        errors = [line for line in lines if line.startswith("ERROR") or "Error" in line]
        why = (errors or lines or [f"exit {done.returncode}"])[0]
        raise BuildError(f"building the LeRobot side environment: {what} failed ({why}); its output: {log}")
    return done.stdout
