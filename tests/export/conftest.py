"""The runs the export tests read: two short sim runs recorded by the project (one with the stereo pair),
and a hand-and-command run written through the recorder with a hardware loop's timing, off the grid; and
the interpreter of LeRobot's side environment (tests/export/lerobot_env), built on first use."""

from pathlib import Path

import numpy as np
import pytest

import twin
from tests.export import lerobot_env
from twin.recording import RunWriter
from twin.rig import command_stream_spec, hand_stream_spec

OFF_GRID_S = (0.0, 0.036, 0.070, 0.170, 0.180, 0.205, 0.233)
"""Hand readings of a 30 Hz loop that ran late (+3 ms), stalled over two periods (0.07 -> 0.17 s) and
caught up (two readings 10 ms apart): what a loaded host does to a hardware run."""


def write_off_grid_run(path: Path, velocity_unit: str = "counts/0.01s") -> Path:
    """A complete run of OFF_GRID_S readings (reading k at 100 k counts) and the command answering each
    2 ms later (set point 1000 k), through the recorder and the rig's own stream specs."""
    writer = RunWriter(path, {"experiment": {"name": "compress", "object": "block"}, "backend": "hardware"})
    writer.add_streams(hand_stream_spec(30.0, velocity_unit), command_stream_spec(30.0))
    for k, t in enumerate(OFF_GRID_S):
        reading = {
            "position_counts": np.full(4, 100 * k),
            "velocity_counts": np.full(4, k),
            "strain_counts": np.full(3, 128),
            "position_rad": np.zeros(4),
            "velocity_rad_s": np.zeros(4),
            "torque_nm": np.zeros(3),
            "force_kg": np.zeros(3),
        }
        writer.append("hand", t, reading)
        writer.append(
            "command",
            t + 0.002,
            {"position_counts": np.full(4, 1000.0 * k), "max_velocity_counts_s": 1e4, "phase": 0},
        )
    writer.close("complete")
    return path


@pytest.fixture(scope="package")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("runs")
    twin.compress(twin.sim_backend("block", seed=2, cameras=True), duration_s=1.5, out=root / "cam")
    twin.compress(twin.sim_backend("soft_block", seed=3), duration_s=2, out=root / "plain")
    write_off_grid_run(root / "hardware" / "plain")  # the same directory name as the sim run's
    return {"cam": root / "cam", "plain": root / "plain", "off_grid": root / "hardware" / "plain"}


@pytest.fixture(scope="session")
def lerobot_python() -> Path:
    """An interpreter with lerobot 0.4.4: $TWIN_LEROBOT_PYTHON, else the side environment, built once into
    the user's cache (tests/export/lerobot_env). A build that fails (no registry, no network) fails the
    tests that need it, in one line: a skip would let the suite pass without LeRobot having read a thing."""
    try:
        return lerobot_env.lerobot_python()
    except lerobot_env.BuildError as error:
        failure = str(error)
    pytest.fail(
        f"{failure}. Offline, TWIN_LEROBOT_PYTHON may name an interpreter with lerobot 0.4.4 instead "
        "(docs/api.md, Export), and -m 'not network' leaves these tests out",
        pytrace=False,
    )
