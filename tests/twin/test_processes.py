"""run_killable: C code's work in a child process that an interrupt kills, its result or its error
handed back as if it ran here, and a child that dies said in one line."""

import os
import signal

import pytest

from twin.interface.errors import ConfigError, TwinError, WorkerLostError
from twin.processes import run_killable, worker_pool


def _square(x: int) -> int:
    return x * x


def _refuse(what: str) -> None:
    raise ConfigError(f"refused: {what}")


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)  # as the OOM killer would


def _die_on(_item: int) -> None:
    _die()


def test_the_childs_result_and_its_error_come_back_as_if_run_here():
    assert run_killable(_square, 12) == 144
    with pytest.raises(ConfigError, match="refused: this"):
        run_killable(_refuse, "this")


def test_a_child_killed_mid_work_is_a_twin_error_naming_it():
    with pytest.raises(WorkerLostError, match="_die ended abruptly") as caught:
        run_killable(_die)
    assert isinstance(caught.value, TwinError)  # the CLI prints it as one line


UNGUARDED_SCRIPT = """
from twin.interface.errors import WorkerLostError
from twin.processes import worker_pool

try:
    with worker_pool(2) as pool:
        print(list(pool.map(abs, [-1, -2])))
except WorkerLostError as error:
    print(f"lost: {error}")
"""


def test_a_script_without_a_main_guard_is_told_so_not_that_its_worker_was_killed(tmp_path):
    """Python's spawn runs a script's top level again in each worker: without `if __name__ ==
    "__main__":` the worker fails as it starts, which is not a kill or a lack of memory."""
    import subprocess
    import sys

    script = tmp_path / "unguarded.py"
    script.write_text(UNGUARDED_SCRIPT)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    (line,) = [x for x in done.stdout.splitlines() if x.startswith("lost: ")]
    assert "failed as it started (exit status 1" in line and 'if __name__ == "__main__":' in line
    assert "out of memory" not in line
    guarded = tmp_path / "guarded.py"
    body = "".join(f"    {x}\n" for x in UNGUARDED_SCRIPT.strip().splitlines())
    guarded.write_text(f'if __name__ == "__main__":\n{body}')
    done = subprocess.run([sys.executable, str(guarded)], capture_output=True, text=True, timeout=120)
    assert done.stdout.strip() == "[1, 2]", done.stderr


def test_a_pool_worker_killed_mid_work_is_said_to_be_killed_not_to_have_failed_as_it_started():
    """The other side of the main-guard message: a pool worker SIGKILLed at its work (as the OOM killer
    would) is a kill, whatever exit status the pool's other workers got as they were ended."""
    killed = r"ended abruptly \(killed, or out of memory\)"
    with pytest.raises(WorkerLostError, match=killed), worker_pool(2) as pool:
        list(pool.map(_die_on, [1, 2]))
