"""`twin export --format lerobot`: recorded runs as a LeRobot v3.0 dataset, read back with pyarrow, OpenCV
and PIL, and with LeRobot's own code (lerobot 0.4.4, unmodified, in the side environment that
tests/export/lerobot_env builds), against the runs' own streams; bad input in one line. The parquet
tables: test_tables.py."""

import json
import os
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

import twin
from tests.export import lerobot_env
from tests.export.conftest import OFF_GRID_S, write_off_grid_run
from twin.cli import main
from twin.export.frames import STATE_NAMES

STATS = ("min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99")
"""What LeRobot 0.4's recorder keeps per feature, per episode and for the dataset."""


def _column(table, name: str) -> np.ndarray:
    return np.array(table.column(name).to_pylist())


def _episodes(out: Path) -> list[dict]:
    return pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()


def test_lerobot_layout_holds_each_runs_state_action_tactile_and_frames(runs, tmp_path: Path, capsys):
    out = tmp_path / "ds"
    assert main(["export", str(runs["cam"]), str(runs["plain"]), "--out", str(out), "--no-images"]) == 0
    assert "2 episode(s)" in capsys.readouterr().out
    info = json.loads((out / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 30
    assert info["features"]["observation.state"]["names"] == list(STATE_NAMES)
    tactile = info["features"]["observation.environment_state"]
    assert (
        tactile["shape"] == [162]
        and tactile["names"][0] == "f1_tip.r0c0"
        and len(set(tactile["names"])) == 162
    )
    assert (
        "observation.tactile" not in info["features"] and info["features"]["run_time_s"]["dtype"] == "float64"
    )
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    episodes = _episodes(out)
    assert info["total_frames"] == len(data) == sum(e["length"] for e in episodes)
    for e, name in zip(episodes, ("cam", "plain"), strict=True):
        assert e["source_run"] == name and e["source_held_frames"] == e["source_unused_readings"] == 0
        run = twin.open_run(runs[name])
        assert e["source_run_id"] == json.loads((runs[name] / "run.json").read_text())["run_id"]
        rows = slice(e["dataset_from_index"], e["dataset_to_index"])
        hand, command, tactile = run.stream("hand"), run.stream("command"), run.stream("tactile")
        state = _column(data, "observation.state")[rows]
        assert np.array_equal(state[:, :4], hand["position_counts"])
        assert np.array_equal(state[:, 8:], hand["strain_counts"])
        # the command answering reading k (recorded one latency after it, before reading k + 1), as float32
        assert np.array_equal(_column(data, "action")[rows], command["position_counts"].astype(np.float32))
        assert (command.t_s >= hand.t_s).all() and (command.t_s[:-1] < hand.t_s[1:]).all()
        assert np.array_equal(_column(data, "observation.environment_state")[rows], tactile["counts"])
        assert np.array_equal(_column(data, "episode_index")[rows], np.full(len(hand), e["episode_index"]))
        # LeRobot's clock: frame_index / fps (float32); the run's own clock beside it, as recorded
        frame_index = _column(data, "frame_index")[rows]
        assert np.array_equal(frame_index, np.arange(len(hand)))
        timestamp = np.asarray(data.column("timestamp").to_numpy())[rows]
        assert timestamp.dtype == np.float32 and np.array_equal(
            timestamp, (frame_index / 30).astype(np.float32)
        )
        assert np.array_equal(_column(data, "run_time_s")[rows], hand.t_s)
        assert not np.array_equal(timestamp, (hand.t_s - hand.t_s[0]).astype(np.float32))  # sim: 2 ms steps
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


def test_no_file_of_the_dataset_names_where_the_runs_were(runs, tmp_path: Path):
    out = tmp_path / "ds"
    assert main(["export", str(runs["cam"]), str(runs["plain"]), "--out", str(out)]) == 0
    root = str(runs["cam"].parent)
    files = [p for p in out.rglob("*") if p.is_file()]
    assert len(files) == 5  # info, stats, tasks, episodes, data
    for path in files:
        data = path.read_bytes()
        assert root.encode() not in data and str(tmp_path).encode() not in data, path


def _episode_values(run: twin.recording.Run) -> dict[str, np.ndarray]:
    hand = run.stream("hand")
    state = np.concatenate([hand["position_counts"], hand["velocity_counts"], hand["strain_counts"]], axis=1)
    return {
        "observation.state": state,
        "observation.environment_state": run.stream("tactile")["counts"],
        "run_time_s": hand.t_s[:, None],
        "frame_index": np.arange(len(hand))[:, None],
    }


def test_stats_per_episode_and_for_the_dataset_as_lerobots_recorder_writes_them(runs, tmp_path: Path):
    out = tmp_path / "ds"
    assert main(["export", str(runs["cam"]), str(runs["plain"]), "--out", str(out), "--no-images"]) == 0
    info = json.loads((out / "meta/info.json").read_text())
    episodes = _episodes(out)
    for e in episodes:
        assert {f"stats/{f}/{s}" for f in info["features"] for s in STATS} <= set(e), sorted(e)
    stats = json.loads((out / "meta/stats.json").read_text())
    assert set(stats) == set(info["features"]) and all(set(s) == set(STATS) for s in stats.values())
    per_run = [_episode_values(twin.open_run(runs[name])) for name in ("cam", "plain")]
    for feature in per_run[0]:
        for e, run_values in zip(episodes, per_run, strict=True):
            values = run_values[feature]
            got = {s: np.array(e[f"stats/{feature}/{s}"]) for s in STATS}
            assert got["count"].tolist() == [len(values)] and got["mean"].shape == (values.shape[1],)
            assert np.allclose(got["mean"], values.mean(axis=0)) and np.allclose(
                got["std"], values.std(axis=0)
            )
            assert np.array_equal(got["min"], values.min(axis=0)) and np.array_equal(
                got["max"], values.max(axis=0)
            )
            for s in ("q01", "q10", "q50", "q90", "q99"):
                assert np.allclose(
                    got[s], np.quantile(values, int(s[1:]) / 100, axis=0, method="inverted_cdf")
                ), (feature, s)
        pooled = np.concatenate(
            [v[feature] for v in per_run]
        )  # the dataset's min/max/mean/std are exact poolings of the episodes'
        assert stats[feature]["count"] == [len(pooled)]
        assert np.allclose(stats[feature]["mean"], pooled.mean(axis=0))
        assert np.allclose(stats[feature]["std"], pooled.std(axis=0))
        assert np.array_equal(stats[feature]["min"], pooled.min(axis=0))
        lengths = np.array([e["length"] for e in episodes])[:, None]
        q50 = np.array([e[f"stats/{feature}/q50"] for e in episodes])
        assert np.allclose(
            stats[feature]["q50"], (q50 * lengths).sum(axis=0) / lengths.sum()
        )  # LeRobot's mean


def test_image_stats_per_channel_over_the_frames_lerobot_samples(runs, tmp_path: Path):
    out = tmp_path / "img"
    assert main(["export", str(runs["cam"]), "--out", str(out)]) == 0
    (episode,) = _episodes(out)
    stereo = twin.open_run(runs["cam"]).stream("stereo")
    assert episode["length"] == len(stereo) < 100  # a short episode: LeRobot samples every frame
    for side in ("left", "right"):
        # what LeRobot reads (PIL, RGB), strided to about 150 px as it does frames of 300 px and more
        rgb = np.stack(
            [np.asarray(Image.open(_jpeg(j)).convert("RGB"))[::2, ::2] for j in stereo[f"{side}_jpeg"]]
        )
        pixels = rgb.reshape(-1, 3) / 255.0
        got = {s: np.array(episode[f"stats/observation.images.{side}/{s}"]) for s in STATS}
        assert got["count"].tolist() == [len(stereo)]
        for s in STATS[:4] + STATS[5:]:
            assert got[s].shape == (3, 1, 1) and ((got[s] >= 0) & (got[s] <= 1)).all(), s
        assert np.allclose(got["mean"].ravel(), pixels.mean(axis=0), atol=2e-3)
        assert np.allclose(got["std"].ravel(), pixels.std(axis=0), atol=2e-3)
        assert np.allclose(
            got["q50"].ravel(), np.quantile(pixels, 0.5, axis=0, method="inverted_cdf"), atol=2 / 255
        )
        assert got["mean"].ravel()[2] > got["mean"].ravel()[0]  # the scene is bluer than red: RGB, not BGR
    stats = json.loads((out / "meta/stats.json").read_text())
    assert np.array(stats["observation.images.left"]["q99"]).shape == (3, 1, 1)


def _jpeg(values: np.ndarray):
    import io

    return io.BytesIO(bytes(np.asarray(values, dtype=np.uint8)))


def test_a_run_off_the_grid_is_resampled_to_it_and_says_so(runs, tmp_path: Path, capsys):
    out = tmp_path / "ds"
    assert main(["export", str(runs["off_grid"]), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "off the 30 fps grid: 2 of 8 frames repeat the previous reading, 1 reading(s) in no frame" in said
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    # frame k holds the latest reading by (k + 1/2) / 30 s: the stall repeats reading 2 in frames 3 and 4,
    # and of the two readings caught up before frame 5's instant (0.170 and 0.180 s) the later one is used
    reading = [0, 1, 2, 2, 2, 4, 5, 6]
    assert np.array_equal(_column(data, "frame_index"), np.arange(8))
    assert np.array_equal(_column(data, "timestamp"), (np.arange(8) / 30).astype(np.float32))
    assert np.array_equal(_column(data, "run_time_s"), np.array(OFF_GRID_S)[reading])
    assert np.array_equal(_column(data, "observation.state")[:, 0], 100 * np.array(reading))
    assert np.array_equal(_column(data, "action")[:, 0], 1000 * np.array(reading))  # the answer to each
    (episode,) = _episodes(out)
    assert (episode["source_held_frames"], episode["source_unused_readings"]) == (2, 1)


def test_runs_with_the_hands_velocity_in_different_units_are_refused(runs, tmp_path: Path, capsys):
    other = write_off_grid_run(tmp_path / "fast", velocity_unit="counts/2.56e-05s")
    assert main(["export", str(runs["off_grid"]), str(other), "--out", str(tmp_path / "ds")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "hand.velocity_counts" in err and "counts/2.56e-05s" in err, err
    assert not (tmp_path / "ds").exists()


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


READ_WITH_LEROBOT = Path(lerobot_env.__file__).parent / "read_export.py"


def _read_with_lerobot(python: Path, dataset: Path, work: Path) -> tuple[dict, dict[str, np.ndarray]]:
    """What LeRobot's own code makes of `dataset`, run by the side environment's interpreter (read_export.py
    says what it reads): its summary, and every array it handed out."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_LEROBOT_HOME": str(work / "home")}
    out = work / "read"
    argv = [str(python), str(READ_WITH_LEROBOT), str(dataset), str(work), str(out)]
    result = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    with np.load(out.with_suffix(".npz")) as arrays:
        return json.loads(out.with_suffix(".json").read_text()), dict(arrays)


def _assert_episode_equals_run(got: dict[str, np.ndarray], rows: np.ndarray, run: twin.recording.Run):
    """LeRobot's frames `rows` hold the run's readings exactly, as float32 (LeRobot's dtype for every float;
    the counts are integers well inside float32's 24 bits), on LeRobot's clock."""
    hand, command = run.stream("hand"), run.stream("command")
    state = np.concatenate([hand["position_counts"], hand["velocity_counts"], hand["strain_counts"]], axis=1)
    assert np.array_equal(got["observation.state"][rows], state.astype(np.float32))
    assert np.array_equal(got["action"][rows], command["position_counts"].astype(np.float32))
    tactile = run.stream("tactile")["counts"].astype(np.float32)
    assert np.array_equal(got["observation.environment_state"][rows], tactile)
    assert np.array_equal(got["run_time_s"][rows], hand.t_s.astype(np.float32))
    frame_index = got["frame_index"][rows]
    assert np.array_equal(frame_index, np.arange(len(hand)))
    assert np.array_equal(got["timestamp"][rows], (frame_index / 30).astype(np.float32))


@pytest.mark.slow
@pytest.mark.network
def test_lerobots_own_loader_reads_a_camera_less_export_as_recorded(runs, tmp_path: Path, lerobot_python):
    out = tmp_path / "ds"
    assert main(["export", str(runs["cam"]), str(runs["plain"]), "--out", str(out), "--no-images"]) == 0
    summary, got = _read_with_lerobot(lerobot_python, out, tmp_path)
    assert summary["fps"] == 30 and summary["episodes"] == 2 and summary["image_keys"] == []
    assert all(task.startswith("compress: ") for task in summary["tasks"])
    episode = got["episode_index"]
    assert np.array_equal(got["index"], np.arange(len(episode)))
    for index, name in enumerate(("cam", "plain")):
        _assert_episode_equals_run(got, episode == index, twin.open_run(runs[name]))
    # delta_timestamps: the state one frame back, the action one frame ahead, never across an episode's
    # ends (LeRobot repeats the edge frame there and flags it as padding)
    state, action = got["observation.state"], got["action"]
    first = np.r_[True, episode[1:] != episode[:-1]]
    last = np.r_[episode[1:] != episode[:-1], True]
    back, ahead = np.arange(len(episode)) - ~first, np.arange(len(episode)) + ~last
    assert np.array_equal(got["delta/observation.state"][:, 0], state[back])
    assert np.array_equal(got["delta/observation.state"][:, 1], state)
    assert np.array_equal(got["delta/observation.state_is_pad"][:, 0], first)
    assert np.array_equal(got["delta/action"][:, 1], action[ahead])
    assert np.array_equal(got["delta/action_is_pad"][:, 1], last)
    # ACT takes the taxels as its environment state: no camera needed
    assert summary["act_inputs"] == ["observation.environment_state", "observation.state"]
    # LeRobot's delete_episodes re-aggregates the stats from meta/episodes: those of the episode left
    assert summary["left_episodes"] == 1
    plain = twin.open_run(runs["plain"])
    _assert_episode_equals_run(
        {k[5:]: v for k, v in got.items() if k.startswith("left/")}, slice(None), plain
    )
    left = summary["left_stats"]
    assert {"observation.state", "action", "observation.environment_state"} <= set(left)
    values = _episode_values(plain)
    for feature in ("observation.state", "observation.environment_state"):
        stats = left[feature]
        assert stats["count"] == [len(values[feature])] and np.allclose(
            stats["mean"], values[feature].mean(axis=0)
        )
        q99 = np.quantile(values[feature], 0.99, axis=0, method="inverted_cdf")
        assert np.allclose(stats["q99"], q99)


@pytest.mark.slow
@pytest.mark.network
def test_lerobots_own_loader_reads_the_camera_frames_and_decodes_its_own_video_conversion(
    runs, tmp_path: Path, lerobot_python
):
    out = tmp_path / "ds"
    assert main(["export", str(runs["cam"]), "--out", str(out)]) == 0
    summary, got = _read_with_lerobot(lerobot_python, out, tmp_path)
    cameras = ["observation.images.left", "observation.images.right"]
    assert summary["image_keys"] == summary["video_keys"] == cameras
    run = twin.open_run(runs["cam"])
    _assert_episode_equals_run(got, slice(None), run)
    stereo = run.stream("stereo")
    for side, key in zip(("left", "right"), cameras, strict=True):
        # LeRobot's frames: the recorded JPEGs, decoded by PIL as RGB, channels first, in [0, 1]
        rgb = np.stack([np.asarray(Image.open(_jpeg(j)).convert("RGB")) for j in stereo[f"{side}_jpeg"]])
        frames = rgb.transpose(0, 3, 1, 2).astype(np.float32) / 255
        assert np.array_equal(got[key], frames)
        # LeRobot's image-to-video conversion (AV1 at its default quality), read back by LeRobot's decoder,
        # which refuses a frame more than 1e-4 s off its timestamp: every frame decodes, each at its own
        # instant (nearer its own source frame than the frames either side, which a one-frame shift reverses)
        video = got[f"video/{key}"]
        assert video.shape == frames.shape
        own = np.abs(video - frames).mean(axis=(1, 2, 3))
        assert own.max() < 4 / 255  # the codec's loss: a few grey levels in 255
        assert own.mean() < 0.5 * np.abs(video[1:] - frames[:-1]).mean()
        assert own.mean() < 0.5 * np.abs(video[:-1] - frames[1:]).mean()
    video = {k[6:]: v for k, v in got.items() if k.startswith("video/")}
    _assert_episode_equals_run(video, slice(None), run)  # the other features come through unchanged
    # ACT with cameras takes them beside the state and the taxels, from the image and the video dataset
    assert (
        summary["act_inputs"]
        == summary["video_act_inputs"]
        == sorted(["observation.environment_state", "observation.state", *cameras])
    )
