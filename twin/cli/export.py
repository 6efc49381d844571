"""`twin export RUN... --format lerobot|parquet --out DIR`: runs for learning pipelines (twin.export)."""

from __future__ import annotations

import argparse

from twin.validation import new_dir, run_dir


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser(
        "export", help="write runs as a LeRobot dataset (one episode per run) or plain Parquet tables"
    )
    p.add_argument("runs", nargs="+", type=run_dir(), metavar="RUN", help="run directories")
    p.add_argument(
        "--format",
        choices=("lerobot", "parquet"),
        default="lerobot",
        help="lerobot: LeRobot's v3.0 dataset layout; parquet: one table per stream",
    )
    p.add_argument("--out", type=new_dir(), required=True, metavar="DIR", help="a new or empty directory")
    p.add_argument("--no-images", action="store_true", help="lerobot: leave the stereo frames out")
    p.add_argument(
        "--include-incomplete",
        action="store_true",
        help="export runs that did not end 'complete' too (each episode records its run's status)",
    )


def command(args: argparse.Namespace) -> int:
    """Export, then say where and what."""
    from twin.export import export_runs

    out = export_runs(
        args.runs,
        args.out,
        args.format,
        images=not args.no_images,
        include_incomplete=args.include_incomplete,
    )
    if args.format == "lerobot":
        import json

        import pyarrow.parquet as pq

        from twin.export.lerobot import EPISODES_PATH, INDEX_FEATURES, RUN_CLOCK, TACTILE

        info = json.loads((out / "meta" / "info.json").read_text())
        features = [k for k in info["features"] if k not in (*INDEX_FEATURES, RUN_CLOCK)]
        print(
            f"wrote {out}: LeRobot dataset {info['codebase_version']}, {info['total_episodes']} episode(s), "
            f"{info['total_frames']} frames at {info['fps']} fps ({', '.join(features)})"
        )
        absent = {TACTILE: "tactile", "observation.images.left": "observation.images"}
        for name, what in absent.items():
            if name not in features and not (args.no_images and what == "observation.images"):
                print(f"  {what}: left out, not every run recorded it")
        columns = ["source_run", "length", "source_held_frames", "source_unused_readings"]
        episodes = pq.read_table(out / EPISODES_PATH.format(chunk_index=0, file_index=0), columns=columns)
        for e in episodes.to_pylist():
            if e["source_held_frames"] or e["source_unused_readings"]:
                print(
                    f"  {e['source_run']}: off the {info['fps']} fps grid: {e['source_held_frames']} of "
                    f"{e['length']} frames repeat the previous reading, {e['source_unused_readings']} "
                    "reading(s) in no frame (the hand did not keep its rate)"
                )
    else:
        tables = sorted(p.name for p in out.glob("*.parquet"))
        print(f"wrote {out}: {', '.join(tables)} and runs.json ({len(args.runs)} run(s))")
    return 0
