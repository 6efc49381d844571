"""`twin export`: recorded runs as a LeRobot v3.0 dataset and as plain Parquet, read back with pyarrow and
OpenCV (and, where an interpreter with the `lerobot` package is named, with LeRobot's own dataset class)
against the runs' own streams; bad input in one line."""

import json
import os
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

import twin
from twin.cli import main
from twin.export.frames import STATE_NAMES

LEROBOT_PYTHON = os.environ.get("TWIN_LEROBOT_PYTHON")
"""An interpreter with `lerobot` installed: its pins (torch < 2.11, rerun-sdk < 0.27) conflict with this
project's, so it lives in an environment of its own (docs/api.md says how one was made)."""


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("runs")
    twin.compress(twin.sim_backend("block", seed=2, cameras=True), duration_s=1.5, out=root / "cam")
    twin.compress(twin.sim_backend("soft_block", seed=3), duration_s=2, out=root / "plain")
    return {"cam": root / "cam", "plain": root / "plain"}


def _column(table, name: str) -> np.ndarray:
    return np.array(table.column(name).to_pylist())


def test_lerobot_layout_holds_each_runs_state_action_tactile_and_frames(runs, tmp_path: Path, capsys):
    out = tmp_path / "ds"
    assert main(["export", str(runs["cam"]), str(runs["plain"]), "--out", str(out), "--no-images"]) == 0
    assert "2 episode(s)" in capsys.readouterr().out
    info = json.loads((out / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 30
    assert info["features"]["observation.state"]["names"] == list(STATE_NAMES)
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert info["total_frames"] == len(data) == sum(e["length"] for e in episodes)
    for e in episodes:
        run = twin.open_run(e["source_run"])
        rows = slice(e["dataset_from_index"], e["dataset_to_index"])
        hand, command, tactile = run.stream("hand"), run.stream("command"), run.stream("tactile")
        state = _column(data, "observation.state")[rows]
        assert np.array_equal(state[:, :4], hand["position_counts"])
        assert np.array_equal(state[:, 8:], hand["strain_counts"])
        # the command answering reading k (recorded one latency after it, before reading k + 1), as float32
        assert np.array_equal(_column(data, "action")[rows], command["position_counts"].astype(np.float32))
        assert (command.t_s >= hand.t_s).all() and (command.t_s[:-1] < hand.t_s[1:]).all()
        assert np.array_equal(_column(data, "observation.tactile")[rows], tactile["counts"])
        assert np.array_equal(_column(data, "episode_index")[rows], np.full(len(hand), e["episode_index"]))
    tasks = pq.read_table(out / "meta/tasks.parquet")
    assert tasks.column("__index_level_0__").to_pylist()[0].startswith("compress: ")

    with_images = tmp_path / "img"
    assert main(["export", str(runs["cam"]), "--out", str(with_images)]) == 0
    data = pq.read_table(with_images / "data/chunk-000/file-000.parquet")
    stereo = twin.open_run(runs["cam"]).stream("stereo")
    left = data.column("observation.images.left").to_pylist()
    assert left[0]["bytes"] == bytes(np.asarray(stereo["left_jpeg"][0], dtype=np.uint8))
    frame = cv2.imdecode(np.frombuffer(left[-1]["bytes"], np.uint8), cv2.IMREAD_COLOR)
    info = json.loads((with_images / "meta/info.json").read_text())
    assert list(frame.shape) == info["features"]["observation.images.left"]["shape"] == [240, 320, 3]


def test_parquet_tables_hold_every_stream_of_every_run(runs, tmp_path: Path):
    out = tmp_path / "tables"
    argv = ["export", str(runs["plain"]), str(runs["cam"]), "--format", "parquet", "--out", str(out)]
    assert main(argv) == 0
    hand = pq.read_table(out / "hand.parquet")
    for episode, name in enumerate(("plain", "cam")):
        recorded = twin.open_run(runs[name]).stream("hand")
        mine = _column(hand, "episode_index") == episode
        assert np.array_equal(_column(hand, "position_counts")[mine], recorded["position_counts"])
        assert np.array_equal(_column(hand, "t_s")[mine], recorded.t_s)
    stereo = pq.read_table(out / "stereo.parquet")
    assert set(stereo.column("run").to_pylist()) == {"cam"}
    assert json.loads((out / "runs.json").read_text())[1]["metadata"]["backend"] == "sim"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["export", "nowhere", "--out", "x"], "not a run directory"),
        (["export", "RUN", "--format", "csv", "--out", "x"], "invalid choice: 'csv'"),
        (["export", "RUN", "--out", "RUN"], "directory is not empty"),
        (["export", "RUN"], "the following arguments are required: --out"),
    ],
)
def test_bad_input_is_one_line(argv, message, runs, tmp_path: Path, capsys):
    paths = {"RUN": str(runs["plain"]), "x": str(tmp_path / "x"), "nowhere": str(tmp_path / "nowhere")}
    argv = [paths.get(a, a) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("twin: error:") and message in err, err
    assert not (tmp_path / "x").exists()


@pytest.mark.skipif(LEROBOT_PYTHON is None, reason="TWIN_LEROBOT_PYTHON names no interpreter with lerobot")
def test_lerobots_own_dataset_class_reads_the_runs_values(runs, tmp_path: Path):
    out = tmp_path / "ds"
    assert main(["export", str(runs["cam"]), str(runs["plain"]), "--out", str(out), "--no-images"]) == 0
    script = (
        "import json, sys\n"
        "from lerobot.datasets.lerobot_dataset import LeRobotDataset\n"
        "ds = LeRobotDataset('barrett-twin/export', root=sys.argv[1])\n"
        "rows = [ds[i] for i in range(len(ds))]\n"
        "print(json.dumps({'fps': ds.fps, 'episodes': ds.num_episodes, 'task': rows[0]['task'],\n"
        "  'state': [r['observation.state'].tolist() for r in rows],\n"
        "  'tactile': [r['observation.tactile'].tolist() for r in rows],\n"
        "  'episode': [int(r['episode_index']) for r in rows]}))\n"
    )
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    result = subprocess.run([LEROBOT_PYTHON, "-c", script, str(out)], capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    got = json.loads(result.stdout.splitlines()[-1])
    assert got["fps"] == 30 and got["episodes"] == 2 and got["task"].startswith("compress: ")
    episode = np.array(got["episode"])
    for index, name in enumerate(("cam", "plain")):
        run = twin.open_run(runs[name])
        state = np.array(got["state"])[episode == index]
        assert np.array_equal(state[:, :4], run.stream("hand")["position_counts"])
        assert np.array_equal(state[:, 8:], run.stream("hand")["strain_counts"])
        assert np.array_equal(np.array(got["tactile"])[episode == index], run.stream("tactile")["counts"])
