"""Recorded runs in the formats learning pipelines read: LeRobot datasets (v3.0 layout) and plain Parquet.

`export_runs(runs, out, fmt="lerobot")` writes one episode per run; `fmt="parquet"` one table per stream
with every run's rows (pandas, polars, Hugging Face `datasets` read them as they are). Written with
pyarrow alone: the `lerobot` package is not needed to write, only to read it back its own way.
"""

from pathlib import Path

from twin.export.frames import EpisodeFrames, episode_frames
from twin.export.lerobot import write_lerobot
from twin.export.tables import write_tables
from twin.interface.errors import ConfigError

__all__ = ["FORMATS", "EpisodeFrames", "episode_frames", "export_runs", "write_lerobot", "write_tables"]

FORMATS = ("lerobot", "parquet")


def export_runs(runs: list[str | Path], out: str | Path, fmt: str = "lerobot", images: bool = True) -> Path:
    """Write `runs` (run directories) to the new directory `out` as `fmt`; returns `out`.

    `images` (lerobot): the stereo pair's frames as image features where every run recorded them."""
    if fmt not in FORMATS:
        raise ConfigError(f"--format {fmt!r}: choose from {', '.join(FORMATS)}")
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out {out}: exists and is not an empty directory; choose a new one")
    if not runs:
        raise ConfigError("no runs to export")
    if fmt == "lerobot":
        return write_lerobot([Path(r) for r in runs], out, images=images)
    return write_tables([Path(r) for r in runs], out)
