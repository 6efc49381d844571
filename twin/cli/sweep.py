"""`twin sweep`: the shape network's dataset, simulated or from recorded runs."""

from __future__ import annotations

import argparse

from twin.cli.common import WORKERS
from twin.interface.errors import ConfigError
from twin.outputs import check_writable
from twin.validation import duration, integer, out_dir, run_dir, seed


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser(
        "sweep", help="shape-network dataset: many compressions with varied finger trajectories"
    )
    p.add_argument("--objects", nargs="+", default=["sphere"], metavar="NAME", help="library objects")
    p.add_argument(
        "--trajectories", type=integer(1, 100_000), default=16, metavar="N", help="trajectories per object"
    )
    p.add_argument("--workers", type=WORKERS, default=2, metavar="K", help="trajectories run in parallel")
    p.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="where the trajectories run: processes on this machine, or a Ray cluster",
    )
    p.add_argument("--address", help="ray: the cluster's address (default: a local Ray instance)")
    p.add_argument(
        "--duration",
        type=duration(min_s=5.0),
        default=20.0,
        metavar="S",
        help="length of each trajectory (s): > 5 (the grasp takes ~4 s), up to a day",
    )
    p.add_argument("--points", type=integer(3, 10_000), default=32, metavar="n", help="contour points (>= 3)")
    p.add_argument(
        "--surface",
        action="store_true",
        help="also keep the fused 3-D surface as heights on a hand-frame grid (about twice the cost)",
    )
    p.add_argument(
        "--seed",
        type=seed(),
        default=0,
        help="seed of the trajectories and their sensor noise: the same seed gives the same dataset",
    )
    p.add_argument(
        "--out", type=out_dir(), required=True, metavar="DATASET", help="dataset directory (resumable)"
    )
    p.add_argument(
        "--from-runs",
        nargs="+",
        type=run_dir(),
        metavar="RUN",
        help="instead of simulating: add recorded runs with --cameras (sim or hardware) to the dataset",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def cmd_sweep(args: argparse.Namespace) -> int:
    """`twin sweep`: run (or resume) a dataset of trajectories, with a progress bar."""
    from twin.experiments.sweep import check_ray_address, draw_trajectories, sweep, trajectory_from_run
    from twin.sim.foam import get_object

    check_writable(args.out)  # before a trajectory is simulated
    if args.from_runs:
        for run_dir in args.from_runs:
            entry = trajectory_from_run(run_dir, args.out, points=args.points)
            print(f"{run_dir}: {entry['samples']} samples -> {args.out / entry['file']}")
        return 0

    for name in args.objects:
        get_object(name)  # unknown names fail here, in one line (the numbers were checked by argparse)
    if args.address is not None:
        if args.executor != "ray":
            raise ConfigError("--address is for --executor ray")
        check_ray_address(args.address)  # before the progress bar: ray.init would retry for minutes
    trajectories = draw_trajectories(
        args.objects, args.trajectories, args.seed, args.duration, args.points, surface=args.surface
    )
    kwargs = {"workers": args.workers, "executor": args.executor, "address": args.address}
    if args.no_progress:
        entries = sweep(trajectories, args.out, **kwargs)
    else:
        from rich.progress import Progress

        with Progress() as bar:
            task = bar.add_task("trajectories", total=len(trajectories))
            entries = sweep(
                trajectories,
                args.out,
                progress=lambda done, total: bar.update(task, completed=done),
                **kwargs,
            )
    samples = sum(e["samples"] for e in entries)
    print(f"dataset {args.out}: {len(entries)} trajectories, {samples} samples")
    return 0


command = cmd_sweep
