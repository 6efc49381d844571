"""The Python API refuses bad input with a ConfigError before anything is created (issue 37): a run's
duration, its name (it names the run directory), a seed."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

import twin
from twin import HandCommand
from twin.interface.errors import ConfigError


def hold(reading) -> HandCommand:
    return HandCommand(np.zeros(4))


@pytest.mark.parametrize("duration_s", [math.inf, -math.inf, math.nan, 0.0, 5e-324, -1.0, 1e9, "5", True])
def test_a_bad_duration_is_refused_before_the_run_directory_exists(duration_s, tmp_path: Path):
    backend = twin.sim_backend(None)
    for call in (
        lambda: twin.run(backend, hold, duration_s=duration_s, out=tmp_path / "r"),
        lambda: twin.compress(backend, duration_s=duration_s, out=tmp_path / "r"),
        lambda: twin.free(backend, duration_s=duration_s, out=tmp_path / "r"),
    ):
        with pytest.raises(ConfigError, match="duration_s must be"):
            call()
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("name", ["../../x", "../x", "a/b", "/tmp/x", ".hidden", "", "x" * 65, "a\0b", "é"])
def test_a_run_name_that_is_a_path_is_refused(name: str, tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match="names the run directory"):
        twin.run(twin.sim_backend(None), hold, duration_s=0.1, name=name)
    assert os.listdir(tmp_path) == []


def test_a_plain_name_makes_its_run_under_runs(tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    outcome = twin.run(twin.sim_backend(None), hold, duration_s=0.1, name="my-squeeze_2.b")
    assert outcome.run_dir.parent == Path("runs") and outcome.run_dir.name.startswith("my-squeeze_2.b-none-")


@pytest.mark.parametrize("seed", [-1, 2**32, 1.5, "3", None, True])
def test_a_bad_seed_is_one_config_error(seed):
    with pytest.raises(ConfigError, match="seed must be an integer"):
        twin.sim_backend(None, seed=seed)
