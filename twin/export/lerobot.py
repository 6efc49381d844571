"""LeRobot's dataset layout, codebase version v3.0 (lerobot 0.4), written with pyarrow.

    meta/info.json                              fps, features (dtype, shape, names), paths, totals
    meta/stats.json                             every feature's stats over the dataset (see below)
    meta/tasks.parquet                          task strings (the pandas index) -> task_index
    meta/episodes/chunk-000/file-000.parquet    per episode: length, tasks, where its rows are, its
                                                run (id, name, status), its own stats/<feature>/<stat>
    data/chunk-000/file-000.parquet             one row per frame

Features: `observation.state` (hand encoders, velocities and strain gauges, in counts), `action` (the
set points sent, counts), `observation.environment_state` (the 162 taxels' raw counts, named
`<pad>.r<row>c<col>`: LeRobot 0.4 has no tactile feature, and the environment state is the vector its
ACT and Diffusion policies take beside the robot's state), where every run recorded the stereo pair
`observation.images.left` / `.right` (the recorded JPEG frames as `image` features, no re-encoding),
and `run_time_s`, the run clock of each frame's hand reading (float64 s; no `observation.` prefix, so
no policy takes it as an input). `timestamp` is `frame_index / fps`, as LeRobot's recorder writes it;
the frames are the run's hand readings put on that grid (twin.export.frames). Values are float32, as
LeRobot stores state and action.

Stats, as LeRobot 0.4's recorder writes them: per episode (the `stats/<feature>/<stat>` columns of
meta/episodes) min, max, mean, std (population), count and the quantiles q01, q10, q50, q90, q99 of
every feature; images per channel (shape (3, 1, 1)) over the frames LeRobot samples from an episode
(all of a short one, about n^0.75 of a long one, evenly spaced; count: the frames sampled), read as RGB,
strided to about 150 px when wider or taller than 300 px, divided by 255. A quantile q is the
ceil(q n)-th smallest value (the inverse of the empirical distribution), the value LeRobot's recorder
estimates from a 5000-bin histogram (its estimate lies within a bin, a 5000th of the feature's range,
of this one). The images' std is the true one: LeRobot 0.4.4's recorder squares the uint8 pixels in
uint8, which wraps, and writes a wrong std (0 for uniform noise); later LeRobot casts first.
meta/stats.json aggregates the episodes' stats as LeRobot 0.4 does (count-weighted mean, pooled
variance, min of mins, max of maxes, count-weighted mean of each quantile), so its dataset tools,
which re-aggregate from meta/episodes, arrive at the same numbers.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from twin.export.frames import ACTION_NAMES, STATE_NAMES, EpisodeFrames, episode_frames
from twin.export.identity import run_id, run_names
from twin.interface.devices import N_TAXELS
from twin.interface.errors import ConfigError

CODEBASE_VERSION = "v3.0"
ROBOT_TYPE = "barrett_bh8"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
IMAGE_TYPE = pa.struct([("bytes", pa.binary()), ("path", pa.string())])
"""How Hugging Face `datasets` stores an Image feature in Arrow (encoded bytes, optional path)."""
TACTILE = "observation.environment_state"
"""Where the taxels go: the observation vector LeRobot's ACT and Diffusion policies read beside the state."""
RUN_CLOCK = "run_time_s"
"""The run clock of each frame's hand reading (not an `observation.*`: no policy input)."""
QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}
"""The quantiles LeRobot 0.4 keeps in its stats (pi0.5's default normalisation reads q01 and q99)."""
INDEX_FEATURES = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def taxel_names() -> list[str]:
    """The 162 taxels in id order as `<pad>.r<row>c<col>` (twin.tactile.layout)."""
    from twin.tactile.layout import LAYOUT

    pads = [LAYOUT.pad_names[p] for p in LAYOUT.pad_index]
    return [f"{pad}.r{r}c{c}" for pad, (r, c) in zip(pads, LAYOUT.row_col, strict=True)]


def _vector(values: np.ndarray) -> pa.FixedSizeListArray:
    """(n, k) float32 as a fixed-size list column (`datasets.Sequence(length=k)`)."""
    values = np.ascontiguousarray(values, dtype=np.float32)
    return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), values.shape[1])


def _decode_rgb(jpeg: bytes) -> np.ndarray:
    """A JPEG as an (h, w, 3) RGB uint8 array (as PIL, which LeRobot reads images with, gives it)."""
    import cv2

    frame = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    if frame is None:
        raise ConfigError("a recorded stereo frame is not a readable JPEG")
    return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)


def _features(first: EpisodeFrames, tactile: bool, images: bool) -> dict:
    features = {
        "observation.state": {"dtype": "float32", "shape": [len(STATE_NAMES)], "names": list(STATE_NAMES)},
        "action": {"dtype": "float32", "shape": [len(ACTION_NAMES)], "names": list(ACTION_NAMES)},
    }
    if tactile:
        features[TACTILE] = {"dtype": "float32", "shape": [N_TAXELS], "names": taxel_names()}
    if images:
        for side in ("left", "right"):
            frame = _decode_rgb(first.images[side][0])
            features[f"observation.images.{side}"] = {
                "dtype": "image",
                "shape": list(frame.shape),
                "names": ["height", "width", "channel"],
            }
    features[RUN_CLOCK] = {"dtype": "float64", "shape": [1], "names": None}
    for name, dtype in zip(INDEX_FEATURES, ("float32", "int64", "int64", "int64", "int64"), strict=True):
        features[name] = {"dtype": dtype, "shape": [1], "names": None}
    return features


def _stats(values: np.ndarray, count: int | None = None) -> dict[str, np.ndarray]:
    """min, max, mean, std, count and quantiles of each column of (n, k) values, in float64."""
    values = np.asarray(values, dtype=np.float64)
    stats = {
        "min": values.min(axis=0),
        "max": values.max(axis=0),
        "mean": values.mean(axis=0),
        "std": values.std(axis=0),
        "count": np.array([len(values) if count is None else count]),
    }
    for key, q in QUANTILES.items():
        stats[key] = np.quantile(values, q, axis=0, method="inverted_cdf")
    return stats


def _sampled(n: int) -> np.ndarray:
    """The frames LeRobot's recorder samples for an episode's image stats: all of up to 100, then about
    n^0.75 (at most 10,000), evenly spaced from the first to the last."""
    count = max(min(n, 100), min(int(n**0.75), 10_000))
    return np.round(np.linspace(0, n - 1, count)).astype(int)


def _image_stats(jpegs: list[bytes]) -> dict[str, np.ndarray]:
    """Per-channel stats of the sampled frames, [0, 1], each of shape (3, 1, 1) (count: frames used).

    Counted in a 256-bin histogram per channel, exact for 8-bit pixels, in constant memory."""
    at = _sampled(len(jpegs))
    histogram = np.zeros((3, 256), dtype=np.int64)
    for i in at:
        rgb = _decode_rgb(jpegs[i])
        h, w = rgb.shape[:2]
        if max(h, w) >= 300:  # LeRobot strides big frames down to about 150 px before its stats
            step = int(w / 150) if w > h else int(h / 150)
            rgb = rgb[::step, ::step]
        for c in range(3):
            histogram[c] += np.bincount(rgb[..., c].ravel(), minlength=256)
    levels = np.arange(256, dtype=np.float64)
    total = histogram.sum(axis=1)
    mean = histogram @ levels / total
    seen = histogram > 0
    stats = {
        "min": np.argmax(seen, axis=1).astype(np.float64),
        "max": 255.0 - np.argmax(seen[:, ::-1], axis=1),
        "mean": mean,
        "std": np.sqrt(np.maximum(histogram @ levels**2 / total - mean**2, 0.0)),
    }
    cumulative = np.cumsum(histogram, axis=1)
    for key, q in QUANTILES.items():  # the ceil(q n)-th smallest pixel, as np.quantile's inverted_cdf
        stats[key] = np.array(
            [np.searchsorted(cumulative[c], q * total[c]) for c in range(3)], dtype=np.float64
        )
    out = {k: (v / 255.0).reshape(3, 1, 1) for k, v in stats.items()}
    out["count"] = np.array([len(at)])
    return out


def _aggregate(episodes: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """One feature's stats over episodes, as LeRobot aggregates them."""
    counts = np.array([e["count"][0] for e in episodes], dtype=np.float64)
    total = counts.sum()
    weights = counts.reshape((-1,) + (1,) * np.ndim(episodes[0]["mean"])) / total
    means = np.stack([e["mean"] for e in episodes])
    mean = (means * weights).sum(axis=0)
    variance = ((np.stack([e["std"] for e in episodes]) ** 2 + (means - mean) ** 2) * weights).sum(axis=0)
    out = {
        "min": np.min([e["min"] for e in episodes], axis=0),
        "max": np.max([e["max"] for e in episodes], axis=0),
        "mean": mean,
        "std": np.sqrt(variance),
        "count": np.array([int(total)]),
    }
    for key in QUANTILES:
        out[key] = (np.stack([e[key] for e in episodes]) * weights).sum(axis=0)
    return out


def _plain(stats: dict[str, np.ndarray]) -> dict[str, list]:
    """Stats as JSON / Arrow values: nested lists of floats, count a list of one int."""
    return {
        k: [int(v[0])] if k == "count" else np.asarray(v, dtype=np.float64).tolist() for k, v in stats.items()
    }


def _episode_stats(e: EpisodeFrames, index: int, start: int, task_index: int, features: dict) -> dict:
    """Every feature's stats over one episode (LeRobot's `compute_episode_stats`, see the docstring)."""
    n = len(e)
    columns = {
        "observation.state": e.state,
        "action": e.action,
        TACTILE: e.tactile,
        RUN_CLOCK: e.t_s[:, None],
        "timestamp": e.timestamp[:, None],
        "frame_index": np.arange(n)[:, None],
        "episode_index": np.full((n, 1), index),
        "index": np.arange(start, start + n)[:, None],
        "task_index": np.full((n, 1), task_index),
    }
    stats = {}
    for name, feature in features.items():
        if feature["dtype"] == "image":
            stats[name] = _image_stats(e.images[name.rsplit(".", 1)[1]])
        else:
            stats[name] = _stats(columns[name])
    return stats


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
    names = run_names(runs)
    for field in ("position_counts", "velocity_counts", "strain_counts"):
        units = {
            e.run.streams["hand"].fields[field].unit: name for e, name in zip(episodes, names, strict=True)
        }
        if len(units) > 1:
            raise ConfigError(
                f"hand.{field}: the runs recorded it in different units "
                f"({', '.join(f'{u} in {n}' for u, n in units.items())}); observation.state has one: "
                "export them separately"
            )
    tactile = all(e.tactile is not None for e in episodes)
    with_images = images and all(e.images for e in episodes)
    features = _features(episodes[0], tactile, with_images)
    tasks = list(dict.fromkeys(e.task for e in episodes))

    columns: dict[str, list] = {name: [] for name in features}
    episode_rows = []
    all_stats = []
    start = 0
    for index, e in enumerate(episodes):
        n = len(e)
        task_index = tasks.index(e.task)
        columns["observation.state"].append(_vector(e.state))
        columns["action"].append(_vector(e.action))
        if tactile:
            columns[TACTILE].append(_vector(e.tactile))
        if with_images:
            for side in ("left", "right"):
                column = [{"bytes": b, "path": None} for b in e.images[side]]
                columns[f"observation.images.{side}"].append(pa.array(column, IMAGE_TYPE))
        columns[RUN_CLOCK].append(pa.array(e.t_s, pa.float64()))
        columns["timestamp"].append(pa.array(e.timestamp))
        columns["frame_index"].append(pa.array(np.arange(n, dtype=np.int64)))
        columns["episode_index"].append(pa.array(np.full(n, index, dtype=np.int64)))
        columns["index"].append(pa.array(np.arange(start, start + n, dtype=np.int64)))
        columns["task_index"].append(pa.array(np.full(n, task_index, dtype=np.int64)))
        stats = _episode_stats(e, index, start, task_index, features)
        all_stats.append(stats)
        row = {
            "episode_index": index,
            "tasks": [e.task],
            "length": n,
            "data/chunk_index": 0,
            "data/file_index": 0,
            "dataset_from_index": start,
            "dataset_to_index": start + n,
            "meta/episodes/chunk_index": 0,
            "meta/episodes/file_index": 0,
            "source_run": names[index],
            "source_run_id": run_id(e.run),
            "source_status": e.run.status,
            "source_held_frames": e.held,
            "source_unused_readings": e.unused,
        }
        for name, feature_stats in stats.items():
            row.update({f"stats/{name}/{k}": v for k, v in _plain(feature_stats).items()})
        episode_rows.append(row)
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

    stats = {name: _plain(_aggregate([s[name] for s in all_stats])) for name in features}
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
