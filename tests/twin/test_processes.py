"""run_killable: C code's work in a child process that an interrupt kills, its result or its error
handed back as if it ran here, and a child that dies said in one line."""

import os
import signal

import pytest

from twin.interface.errors import ConfigError, TwinError, WorkerLostError
from twin.processes import run_killable


def _square(x: int) -> int:
    return x * x


def _refuse(what: str) -> None:
    raise ConfigError(f"refused: {what}")


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)  # as the OOM killer would


def test_the_childs_result_and_its_error_come_back_as_if_run_here():
    assert run_killable(_square, 12) == 144
    with pytest.raises(ConfigError, match="refused: this"):
        run_killable(_refuse, "this")


def test_a_child_killed_mid_work_is_a_twin_error_naming_it():
    with pytest.raises(WorkerLostError, match="_die ended abruptly") as caught:
        run_killable(_die)
    assert isinstance(caught.value, TwinError)  # the CLI prints it as one line
