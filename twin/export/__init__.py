"""Recorded runs in the formats learning pipelines read: LeRobot datasets (v3.0 layout) and plain Parquet.

`export_runs(runs, out, fmt="lerobot")` writes one episode per run; `fmt="parquet"` one table per stream
with every run's rows (pandas, polars, Hugging Face `datasets` read them as they are). Written with
pyarrow alone: the `lerobot` package is not needed to write, only to read it back its own way.

Only runs that ended `complete` are exported unless `include_incomplete` (each episode records its run's
status), a run is never exported twice into one dataset (a train/test leak), and `out` appears whole or
not at all (twin.outputs.new_directory: concurrent exports into one `out` cannot both succeed).
"""

from pathlib import Path

from twin.export.frames import EpisodeFrames, episode_frames
from twin.export.identity import run_id
from twin.export.lerobot import write_lerobot
from twin.export.tables import write_tables
from twin.interface.errors import ConfigError
from twin.outputs import check_new_directory, new_directory
from twin.recording import open_run

__all__ = ["FORMATS", "EpisodeFrames", "episode_frames", "export_runs", "write_lerobot", "write_tables"]

FORMATS = ("lerobot", "parquet")


def export_runs(
    runs: list[str | Path],
    out: str | Path,
    fmt: str = "lerobot",
    images: bool = True,
    *,
    include_incomplete: bool = False,
) -> Path:
    """Write `runs` (run directories) to the new directory `out` as `fmt`; returns `out`.

    `images` (lerobot): the stereo pair's frames as image features where every run recorded them.
    `include_incomplete`: export runs whose status is not `complete` too (killed, failed, interrupted,
    still being written)."""
    if fmt not in FORMATS:
        raise ConfigError(f"--format {fmt!r}: choose from {', '.join(FORMATS)}")
    out = Path(out)
    if not runs:
        raise ConfigError("no runs to export")
    check_new_directory(out)
    paths = _checked_runs([Path(r) for r in runs], include_incomplete)
    with new_directory(out) as tmp:
        if fmt == "lerobot":
            write_lerobot(paths, tmp, images=images)
        else:
            write_tables(paths, tmp)
    return out


def _checked_runs(paths: list[Path], include_incomplete: bool) -> list[Path]:
    """The runs, each readable, complete (unless include_incomplete) and named once."""
    seen: dict[object, Path] = {}
    for path in paths:
        run = open_run(path)
        if run.status != "complete" and not include_incomplete:
            raise ConfigError(
                f"{path}: the run's status is {run.status!r}, not 'complete' (killed, failed, interrupted "
                "or still being written); --include-incomplete exports it anyway, its status recorded"
            )
        for key in (path.resolve(), ("run_id", run_id(run))):
            if key in seen:
                raise ConfigError(
                    f"{path}: the same run as {seen[key]}; a run exported twice is two identical episodes"
                )
            seen[key] = path
    return paths
