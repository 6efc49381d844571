"""`twin train`: the shape network and its baselines on a sweep dataset."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from twin.interface.errors import ConfigError
from twin.outputs import check_writable
from twin.validation import existing_dir, finite, integer, out_dir, seed

if TYPE_CHECKING:
    from twin.shape.surface_train import SurfaceTrainResult as SurfaceResult
    from twin.shape.train import CrossValidation


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser("train", help="train the shape network (6-30-2n) on a sweep dataset, with baselines")
    p.add_argument(
        "dataset",
        type=existing_dir("index.json", "a sweep dataset"),
        metavar="DATASET",
        help="a `twin sweep` directory",
    )
    p.add_argument("--object", required=True, help="the object whose network to train")
    p.add_argument(
        "--target",
        choices=("hull", "largest", "surface"),
        default="hull",
        help="hull (default): the hull of all visible pieces of the object; largest: the largest visible "
        "piece's outline (the paper's, which switches piece when the fingers cut the object into pieces "
        "of similar size); surface: the fused 3-D surface's heights (a dataset swept with --surface)",
    )
    p.add_argument(
        "--out",
        type=out_dir(),
        metavar="DIR",
        help="where the model goes (default DATASET/models/OBJECT for the hull, OBJECT-TARGET otherwise)",
    )
    p.add_argument(
        "--epochs",
        type=integer(1, 10_000_000),
        default=3000,  # twin.shape.train.EPOCHS (that module imports torch)
        help="full-batch training epochs of every network trained",
    )
    p.add_argument(
        "--folds",
        type=integer(2, 100_000),
        metavar="K",
        help="contours: score by K-fold cross-validation over trajectories, every trajectory held out "
        "once (the default: K = 4, or one fold per trajectory where there are fewer); the model kept is "
        "trained on all of them",
    )
    p.add_argument(
        "--validation",
        type=finite(0, 1, min_inclusive=False, max_inclusive=False),
        metavar="F",
        help="score on one held-out fraction F of the trajectories instead (3-D variant: 0.25 by default)",
    )
    p.add_argument(
        "--seed",
        type=seed(),
        default=0,
        help="seed of the networks' initial weights and of the folds' shuffle",
    )
    p.add_argument("--json", action="store_true", help="print the evaluation as JSON")


def cmd_train(args: argparse.Namespace) -> int:
    """`twin train`: the network and its baselines on held-out trajectories (twin.api.shape)."""
    from rich.console import Console
    from rich.progress import Progress

    from twin.api.shape import train_shape_network

    if args.folds is not None and args.validation is not None:  # (also the API's check) before the probe
        raise ConfigError("--folds and --validation: choose one way to hold trajectories out")
    check_writable(args.out or args.dataset / "models")  # before any network is trained
    bar = Progress(console=Console(stderr=True), transient=True, disable=args.json)
    task = None

    def progress(done: int, total: int) -> None:  # drawn from the first network on, after every check
        nonlocal task
        if task is None:
            bar.start()
            task = bar.add_task(f"networks ({total - 1} folds, then all trajectories)", total=total)
        bar.update(task, completed=done)

    try:
        outcome = train_shape_network(
            args.dataset,
            args.object,
            target=args.target,
            out=args.out,
            epochs=args.epochs,
            folds=args.folds,
            validation=args.validation,
            seed=args.seed,
            progress=progress,
        )
    finally:
        if task is not None:
            bar.stop()
    if args.json:
        print(json.dumps(outcome.report, indent=1))
        return 0
    result = outcome.result
    if args.target == "surface":
        _print_surface(result)
    elif outcome.folds is not None:
        _print_folds(result, outcome.folds)
    else:
        print(
            f"{result.train_samples} training samples; held out trajectories {result.validation_trajectories}"
        )
        _print_evaluations(result.evaluations)
    trained_on = " (trained on every trajectory)" if outcome.folds is not None else ""
    print(f"wrote {outcome.model_dir}{trained_on}")
    return 0


def _print_evaluations(evaluations: list) -> None:
    for e in evaluations:
        print(
            f"  {e.name:28s} {e.error_px:6.2f} px  {e.error_mm:6.2f} mm  "
            f"({e.error_px_smoothed:.2f} px vs smoothed contours)"
        )


def _print_folds(result: CrossValidation, folds: int) -> None:
    from twin.shape.train import NETWORK

    worst = max(result.trajectory_errors_px, key=result.trajectory_errors_px.get)
    print(
        f"{result.samples} samples, {len(result.trajectory_errors_px)} trajectories in {folds} folds: "
        "each trajectory held out once"
    )
    _print_evaluations(result.evaluations)
    folds_px = ", ".join(f"{e:.2f}" for e in result.fold_errors_px[NETWORK])
    print(
        f"  network per fold: {folds_px} px; worst trajectory {worst}: "
        f"{result.trajectory_errors_px[worst]:.2f} px"
    )


def _print_surface(result: SurfaceResult) -> None:
    print(f"{result.train_samples} training samples; held out trajectories {result.validation_trajectories}")
    print(
        f"  {result.modelled_cells} grid cells modelled; {100 * result.observed_fraction:.0f} % of held-out "
        f"cells observed; measured heights vs the true surface: {result.measured_truth_error_mm:.2f} mm"
    )
    for e in result.evaluations:
        print(f"  {e.name:28s} {e.error_mm:6.2f} mm vs measured  {e.truth_error_mm:6.2f} mm vs true surface")


command = cmd_train
