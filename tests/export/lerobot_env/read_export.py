"""Run by the LeRobot side environment's interpreter (tests/export/test_export.py): read an exported
dataset with lerobot 0.4.4's own code and write what it gave to OUT.npz (arrays) and OUT.json.

    python read_export.py DATASET WORK_DIR OUT

Every frame of every feature as `LeRobotDataset` hands it out; the state and action with
`delta_timestamps` (the frame before and after); the features ACT's config accepts or its error; with two
or more episodes, the dataset left by `delete_episodes` (episode 0 deleted), its frames and stats; with
cameras, the dataset made by `convert_image_to_video_dataset`, every frame decoded."""

import json
import sys
from pathlib import Path

import numpy as np
import torch
from lerobot.configs.types import FeatureType
from lerobot.datasets.dataset_tools import convert_image_to_video_dataset, delete_episodes
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.utils import dataset_to_policy_features
from lerobot.policies.act.configuration_act import ACTConfig

REPO_ID = "barrett-twin/export"


def frames(ds: LeRobotDataset, prefix: str) -> dict[str, np.ndarray]:
    """Every item of `ds`, each tensor feature stacked over the frames, keys prefixed."""
    items = [ds[i] for i in range(len(ds))]
    return {
        f"{prefix}{key}": np.stack([item[key].numpy() for item in items])
        for key, value in items[0].items()
        if isinstance(value, torch.Tensor)
    }


def act_inputs(ds: LeRobotDataset) -> list[str] | str:
    """The input features of an ACT config built from the dataset's features, or why ACT refused them."""
    features = dataset_to_policy_features(ds.meta.features)
    try:
        act = ACTConfig(
            input_features={k: f for k, f in features.items() if f.type is not FeatureType.ACTION},
            output_features={k: f for k, f in features.items() if f.type is FeatureType.ACTION},
        )
        act.validate_features()
    except ValueError as error:
        return str(error)
    return sorted(act.input_features)


def stats(ds: LeRobotDataset) -> dict[str, dict[str, list]]:
    return {k: {s: np.asarray(v).tolist() for s, v in st.items()} for k, st in ds.meta.stats.items()}


def main(dataset: Path, work: Path, out: Path) -> None:
    ds = LeRobotDataset(REPO_ID, root=dataset, video_backend="pyav")
    arrays = frames(ds, "")
    summary = {
        "fps": ds.fps,
        "episodes": ds.num_episodes,
        "tasks": sorted({ds[i]["task"] for i in range(len(ds))}),
        "act_inputs": act_inputs(ds),
        "image_keys": ds.meta.image_keys,
    }
    step = 1 / ds.fps
    delta = {"observation.state": [-step, 0.0], "action": [0.0, step]}
    arrays |= frames(LeRobotDataset(REPO_ID, root=dataset, delta_timestamps=delta), "delta/")
    if ds.num_episodes > 1:
        delete_episodes(ds, [0], output_dir=work / "left", repo_id=f"{REPO_ID}-left")
        left = LeRobotDataset(f"{REPO_ID}-left", root=work / "left")
        arrays |= frames(left, "left/")
        summary["left_stats"] = stats(left)
        summary["left_episodes"] = left.num_episodes
    if ds.meta.image_keys:
        convert_image_to_video_dataset(ds, work / "video", repo_id=f"{REPO_ID}-video", num_workers=1)
        video = LeRobotDataset(f"{REPO_ID}-video", root=work / "video", video_backend="pyav")
        summary["video_keys"] = video.meta.video_keys
        summary["video_act_inputs"] = act_inputs(video)
        arrays |= frames(video, "video/")
    np.savez(out.with_suffix(".npz"), **arrays)
    out.with_suffix(".json").write_text(json.dumps(summary))


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]))
