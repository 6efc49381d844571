"""`twin fit`: the twin's foam parameters that reproduce a run (real-to-sim)."""

from __future__ import annotations

import argparse
import sys

from twin.cli.common import SIZE_MM, WORKERS, YOUNG_PA, run_metadata
from twin.interface.errors import ConfigError
from twin.outputs import check_writable
from twin.validation import out_dir, run_dir


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser("fit", help="fit the twin's foam to a run by replaying its commands (real-to-sim)")
    p.add_argument(
        "run_dir", type=run_dir(), metavar="RUN", help="a run directory (sim or hardware) with commands"
    )
    p.add_argument(
        "--params",
        nargs="+",
        choices=("young_pa", "damping", "poisson"),
        default=["young_pa", "damping", "poisson"],
        help="foam parameters to fit",
    )
    p.add_argument("--workers", type=WORKERS, default=2, help="replays in parallel (processes)")
    p.add_argument("--object", help="library object to put in the twin, for runs that do not describe theirs")
    p.add_argument(
        "--size-mm", type=SIZE_MM, nargs=3, metavar=("X", "Y", "Z"), help="with --object: its extents"
    )
    p.add_argument("--young", type=YOUNG_PA, metavar="PA", help="first guess of E (default: scan the range)")
    p.add_argument("--json", action="store_true", help="also print the results file")
    p.add_argument("--out", type=out_dir(), metavar="DIR", help="where the results go (default RUN/fit)")
    p.add_argument("--no-progress", action="store_true", help="no progress line")


def cmd_fit(args: argparse.Namespace) -> int:
    """`twin fit`: the twin's foam parameters that reproduce a run, and the files that show them."""
    if args.size_mm is not None and args.object is None:
        raise ConfigError("--size-mm needs --object (the library object it resizes)")
    run_metadata(args.run_dir, "RUN")
    foam = None
    if args.object is not None:
        from twin.sim.foam import get_object

        size = tuple(s / 1e3 for s in args.size_mm) if args.size_mm else None
        foam = get_object(args.object).with_overrides(size_m=size)  # unknown or ill-fitting: one line
    check_writable(args.out or args.run_dir / "fit")  # every input checked; before minutes of replays
    from twin.sim.fit import fit_run
    from twin.sim.fit_report import write_fit

    most = _replays_at_most(args.params, young_given=args.young is not None)

    def progress(replays: int, wall_s: float) -> None:
        if not args.no_progress:
            left_s = wall_s / replays * max(most - replays, 0) if replays else float("nan")
            print(
                f"\r  {replays} of at most {most} replays, {wall_s:.0f} s; at most ~{left_s:.0f} s left   ",
                end="",
                file=sys.stderr,
                flush=True,
            )

    initial = {"young_pa": args.young} if args.young is not None else None
    result = fit_run(
        args.run_dir, names=args.params, workers=args.workers, initial=initial, progress=progress, foam=foam
    )
    if not args.no_progress:
        print(file=sys.stderr)
    paths = write_fit(result, args.out or args.run_dir / "fit")
    if args.json:
        print(paths["results"].read_text(), end="")
        return 0
    for name in result.names:
        line = f"{name}: {result.fitted[name]:.5g} (first guess {result.initial[name]:.4g})"
        if not result.identifiable[name]:
            line += "  not identifiable from this run"
        if name in result.twin_truth:
            truth = result.twin_truth[name]
            line += f"; the twin's {truth:.4g}, error {100 * (result.fitted[name] / truth - 1):+.2f} %"
        print(line)
    print(
        "rms "
        + ", ".join(
            f"{k} {result.rms_initial[k]:.3g} -> {result.rms_fitted[k]:.3g}" for k in result.rms_fitted
        )
    )
    print(f"{result.evaluations} replays of {result.window_s:.1f} s in {result.wall_s:.0f} s")
    print(f"wrote {paths['results']}, {paths['figure'].name}")
    return 0


def _replays_at_most(names: list[str], young_given: bool) -> int:
    """An upper bound on the replays twin.sim.fit.fit_run makes, for the progress line's total and ETA
    (its progress callback reports replays done, not planned; cached repeats make the real count lower).

    Mirrors fit_run's stages: the modulus grid-zoomed (4 stages from a scan, 3 from a given start), each
    other parameter's profile (two probes, each re-zooming the modulus) and, if identifiable, its own zoom
    and a modulus re-zoom, then at most POLISH_EVALUATIONS least-squares steps of a Jacobian each, and
    the modulus's final probes."""
    from twin.sim.fit import POLISH_EVALUATIONS, ZOOM_POINTS

    young = "young_pa" in names
    total = 1 + (3 if young_given else 4) * ZOOM_POINTS if young else 0
    remezoom = 1 + 2 * ZOOM_POINTS if young else 0
    for _ in (n for n in names if n != "young_pa"):
        total += 1 + 2 * (remezoom if young else 1) + (1 + 3 * ZOOM_POINTS) + remezoom
    return total + POLISH_EVALUATIONS * (1 + len(names)) + 4


command = cmd_fit
