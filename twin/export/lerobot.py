"""LeRobot's dataset layout, codebase version v3.0 (lerobot 0.4), written with pyarrow.

    meta/info.json                              fps, features (dtype, shape, names), paths, totals
    meta/stats.json                             min/max/mean/std/count of each numeric feature
    meta/tasks.parquet                          task strings (the pandas index) -> task_index
    meta/episodes/chunk-000/file-000.parquet    per episode: length, tasks, where its rows are
    data/chunk-000/file-000.parquet             one row per frame

Features: `observation.state` (hand encoders, velocities and strain gauges, in counts), `action` (the
set points sent, counts), `observation.tactile` (the 162 taxels' raw counts: LeRobot 0.4 has no tactile
feature of its own; an `observation.*` vector is what its policies take as an input) and, where every
run recorded the stereo pair, `observation.images.left` / `.right` (the recorded JPEG frames as
`image` features, no re-encoding). Values are float32, as LeRobot stores state and action.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from twin.export.frames import ACTION_NAMES, STATE_NAMES, EpisodeFrames, episode_frames
from twin.interface.devices import N_TAXELS
from twin.interface.errors import ConfigError

CODEBASE_VERSION = "v3.0"
ROBOT_TYPE = "barrett_bh8"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
IMAGE_TYPE = pa.struct([("bytes", pa.binary()), ("path", pa.string())])
"""How Hugging Face `datasets` stores an Image feature in Arrow (encoded bytes, optional path)."""


def _vector(values: np.ndarray) -> pa.FixedSizeListArray:
    """(n, k) float32 as a fixed-size list column (`datasets.Sequence(length=k)`)."""
    values = np.ascontiguousarray(values, dtype=np.float32)
    return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), values.shape[1])


def _features(first: EpisodeFrames, tactile: bool, images: bool) -> dict:
    features = {
        "observation.state": {"dtype": "float32", "shape": [len(STATE_NAMES)], "names": list(STATE_NAMES)},
        "action": {"dtype": "float32", "shape": [len(ACTION_NAMES)], "names": list(ACTION_NAMES)},
    }
    if tactile:
        features["observation.tactile"] = {
            "dtype": "float32",
            "shape": [N_TAXELS],
            "names": [f"taxel_{i:03d}" for i in range(N_TAXELS)],
        }
    if images:
        import cv2

        for side in ("left", "right"):
            frame = cv2.imdecode(np.frombuffer(first.images[side][0], np.uint8), cv2.IMREAD_COLOR)
            features[f"observation.images.{side}"] = {
                "dtype": "image",
                "shape": list(frame.shape),
                "names": ["height", "width", "channel"],
            }
    for name, dtype in (
        ("timestamp", "float32"),
        ("frame_index", "int64"),
        ("episode_index", "int64"),
        ("index", "int64"),
        ("task_index", "int64"),
    ):
        features[name] = {"dtype": dtype, "shape": [1], "names": None}
    return features


def _stats(values: np.ndarray) -> dict[str, list[float]]:
    return {
        "min": values.min(axis=0).tolist(),
        "max": values.max(axis=0).tolist(),
        "mean": values.mean(axis=0).tolist(),
        "std": values.std(axis=0).tolist(),
        "count": [len(values)],
    }


def _tasks_table(tasks: list[str]) -> pa.Table:
    """tasks.parquet as pandas writes a DataFrame indexed by the task string (LeRobot reads it so)."""
    table = pa.table({"task_index": pa.array(range(len(tasks)), pa.int64()), "__index_level_0__": tasks})
    pandas_meta = {
        "index_columns": ["__index_level_0__"],
        "column_indexes": [],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
             "numpy_type": "int64", "metadata": None},
            {"name": None, "field_name": "__index_level_0__", "pandas_type": "unicode",
             "numpy_type": "object", "metadata": None},
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.0",
    }  # fmt: skip
    return table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})


def write_lerobot(runs: list[Path], out: Path, images: bool = True) -> Path:
    """Each run an episode of one LeRobot dataset at `out` (see the module docstring)."""
    episodes = [episode_frames(path, images=images) for path in runs]
    fps = {e.fps for e in episodes}
    if len(fps) > 1:
        raise ConfigError(f"the runs' hand rates differ ({sorted(fps)} Hz): a dataset has one fps")
    tactile = all(e.tactile is not None for e in episodes)
    with_images = images and all(e.images for e in episodes)
    features = _features(episodes[0], tactile, with_images)
    tasks = list(dict.fromkeys(e.task for e in episodes))

    columns: dict[str, list] = {name: [] for name in features}
    episode_rows = []
    start = 0
    for index, e in enumerate(episodes):
        n = len(e)
        columns["observation.state"].append(_vector(e.state))
        columns["action"].append(_vector(e.action))
        if tactile:
            columns["observation.tactile"].append(_vector(e.tactile))
        if with_images:
            for side in ("left", "right"):
                column = [{"bytes": b, "path": None} for b in e.images[side]]
                columns[f"observation.images.{side}"].append(pa.array(column, IMAGE_TYPE))
        columns["timestamp"].append(pa.array((e.t_s - e.t_s[0]).astype(np.float32)))
        columns["frame_index"].append(pa.array(np.arange(n, dtype=np.int64)))
        columns["episode_index"].append(pa.array(np.full(n, index, dtype=np.int64)))
        columns["index"].append(pa.array(np.arange(start, start + n, dtype=np.int64)))
        columns["task_index"].append(pa.array(np.full(n, tasks.index(e.task), dtype=np.int64)))
        episode_rows.append(
            {
                "episode_index": index,
                "tasks": [e.task],
                "length": n,
                "data/chunk_index": 0,
                "data/file_index": 0,
                "dataset_from_index": start,
                "dataset_to_index": start + n,
                "meta/episodes/chunk_index": 0,
                "meta/episodes/file_index": 0,
                "source_run": str(e.run.path),
                "source_status": e.run.status,
            }
        )
        start += n

    data = pa.table({name: pa.concat_arrays(parts) for name, parts in columns.items()})
    (out / "meta").mkdir(parents=True, exist_ok=True)
    data_file = out / DATA_PATH.format(chunk_index=0, file_index=0)
    data_file.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(data, data_file)
    episodes_file = out / EPISODES_PATH.format(chunk_index=0, file_index=0)
    episodes_file.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(episode_rows), episodes_file)
    pq.write_table(_tasks_table(tasks), out / "meta" / "tasks.parquet")

    vectors = {"observation.state": "state", "action": "action", "observation.tactile": "tactile"}
    stats = {
        name: _stats(np.concatenate([getattr(e, attr) for e in episodes]))
        for name, attr in vectors.items()
        if name in features
    }
    for name in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
        stats[name] = _stats(np.asarray(data.column(name).to_numpy(), dtype=np.float64)[:, None])
    (out / "meta" / "stats.json").write_text(json.dumps(stats, indent=1))
    info = {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": ROBOT_TYPE,
        "total_episodes": len(episodes),
        "total_frames": start,
        "total_tasks": len(tasks),
        "chunks_size": 1000,
        "data_files_size_in_mb": 100,
        "video_files_size_in_mb": 200,
        "fps": fps.pop(),
        "splits": {"train": f"0:{len(episodes)}"},
        "data_path": DATA_PATH,
        "video_path": None,
        "features": features,
    }
    (out / "meta" / "info.json").write_text(json.dumps(info, indent=2))
    return out
