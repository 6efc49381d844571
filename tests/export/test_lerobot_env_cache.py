"""LeRobot's side environments do not pile up in the user's cache: one of another key left unused for
PRUNE_AFTER_DAYS is removed when the current one is used, never a recent one, one another process holds,
the current one, or anything the builds did not name (real directories, real file locks, no build)."""

import os
import subprocess
import sys
import time
from pathlib import Path

from filelock import FileLock

from tests.export import lerobot_env

DAY_S = 86400.0


def _env(root: Path, name: str, *, used_days_ago: float | None, made_days_ago: float) -> Path:
    env = root / name
    (env / "bin").mkdir(parents=True)
    (env / "bin" / "python").write_text("")
    made = time.time() - made_days_ago * DAY_S
    if used_days_ago is not None:
        stamp = env / ".used"
        stamp.touch()
        used = time.time() - used_days_ago * DAY_S
        os.utime(stamp, (used, used))
    os.utime(env, (made, made))
    return env


def test_an_environment_unused_for_a_month_is_pruned_and_a_recent_or_held_one_is_kept(tmp_path: Path):
    root = tmp_path / "lerobot-env"
    current = _env(root, "0" * 16, used_days_ago=90, made_days_ago=90)
    stale = _env(root, "a" * 16, used_days_ago=40, made_days_ago=100)
    (root / f"{'a' * 16}.build.log").write_text("old build")
    never_stamped = _env(root, "b" * 16, used_days_ago=None, made_days_ago=45)
    recent = _env(root, "c" * 16, used_days_ago=2, made_days_ago=100)  # made long ago, used lately
    held = _env(root, "d" * 16, used_days_ago=60, made_days_ago=60)
    foreign = _env(root, "not-a-build", used_days_ago=None, made_days_ago=365)
    # another process holding the old environment's lock (a suite of another checkout using it now)
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from filelock import FileLock\n"
            f"with FileLock({str(root / (held.name + '.lock'))!r}):\n"
            "    print('held', flush=True); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        removed = lerobot_env.prune_stale(root, keep=current.name)
    finally:
        holder.kill()
        holder.wait()
    assert sorted(removed) == sorted([stale, never_stamped])
    assert not stale.exists() and not never_stamped.exists()
    assert not (root / f"{'a' * 16}.build.log").exists()
    assert current.is_dir() and recent.is_dir() and held.is_dir() and foreign.is_dir()
    # once free, the held one goes too; nothing else changes
    with FileLock(root / f"{held.name}.lock", timeout=5):
        pass
    assert lerobot_env.prune_stale(root, keep=current.name) == [held]
    assert sorted(p.name for p in root.iterdir() if p.is_dir()) == sorted(
        [current.name, recent.name, foreign.name]
    )


def test_using_the_current_environment_stamps_it_and_prunes_the_stale_ones(tmp_path: Path, monkeypatch):
    """`lerobot_python()` itself, on a cache holding a complete environment of the current key: it is
    returned, stamped as used now, and an old one of another key is gone."""
    monkeypatch.delenv("TWIN_LEROBOT_PYTHON", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    root = lerobot_env.cache_root()
    current = _env(root, lerobot_env.key(), used_days_ago=300, made_days_ago=300)
    stale = _env(
        root, "f" * 16 if lerobot_env.key() != "f" * 16 else "e" * 16, used_days_ago=31, made_days_ago=31
    )
    before = time.time()
    assert lerobot_env.lerobot_python() == lerobot_env.interpreter(current)
    assert (current / ".used").stat().st_mtime >= before - 1
    assert not stale.exists()
