"""`twin identify`: eq. 4 per finger and the foam's modulus from a compress run."""

from __future__ import annotations

import argparse
import sys

from twin.cli.common import SIZE_MM, WORKERS, add_mesh_scale, run_metadata
from twin.interface.errors import ConfigError
from twin.outputs import check_writable
from twin.validation import existing_file, experiment_name, finite, out_dir, run_dir


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser(
        "identify", help="eq. 4 per finger and the foam's Young's modulus, from a compress run"
    )
    p.add_argument("run_dir", type=run_dir(), metavar="RUN", help="a `twin run compress` run directory")
    p.add_argument(
        "--free", type=run_dir(), metavar="FREE_RUN", help="a `twin run free` run: the hand's own terms"
    )
    p.add_argument(
        "--model",
        choices=("kelvin-voigt", "hunt-crossley"),
        default="kelvin-voigt",
        help="the fingertip pads' reaction model R(δ, δ̇) fitted in eq. 4",
    )
    p.add_argument("--json", action="store_true", help="also print the results file")
    p.add_argument("--out", type=out_dir(), metavar="DIR", help="where the results go (default RUN/identify)")
    p.add_argument(
        "--shape",
        choices=("block", "cylinder", "sphere"),
        help="the object's shape (default: the run's record)",
    )
    p.add_argument(
        "--size-mm", type=SIZE_MM, nargs=3, metavar=("X", "Y", "Z"), help="with --shape: the object's extents"
    )
    p.add_argument(
        "--object-mesh", type=existing_file(), metavar="FILE", help="the object as a closed .stl/.obj surface"
    )
    add_mesh_scale(p)
    p.add_argument("--workers", type=WORKERS, default=2, help="simulations in parallel (processes)")
    p.add_argument(
        "--precision",
        type=finite(0.0, min_inclusive=False),
        default=15.0,
        metavar="PCT",
        help="give E as a number only where its 95 %% interval is within this many per cent of it; "
        "a wider one ends in the interval alone (default 15)",
    )
    g = p.add_argument_group(
        "tolerances",
        "what the run cannot tell apart, drawn over in every simulation (the interval holds as far as "
        "they do)",
    )
    for flag, said in (  # their bounds and defaults are twin.sim.modulus.Tolerances' (checked there)
        (
            "--placement-tolerance-mm",
            "the object sits within MM of the palm's centre, either axis (default 3)",
        ),
        (
            "--size-tolerance-mm",
            "every described extent is within MM of the object's (default 1; not a mesh)",
        ),
    ):
        g.add_argument(flag, type=finite(0.0), metavar="MM", help=said)
    g.add_argument(
        "--poisson",
        type=finite(0.0),
        nargs=2,
        metavar=("LOW", "HIGH"),
        help="the foam's Poisson ratio lies within these (default 0.2 0.35: flexible polyurethane foams)",
    )
    p.add_argument(
        "--poisson-from-cameras",
        action="store_true",
        help="draw the modulus simulations' Poisson ratios within the two stereo pairs' 95 %% interval "
        "(default: the pairs' reading is reported, the tolerated range drawn; see docs/identification.md)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _described_object(args: argparse.Namespace, metadata: dict):
    """The object the modulus is inferred for: --shape/--size-mm, --object-mesh, or the run's record."""
    from twin.sim.foam import LIBRARY, mesh_object

    if args.object_mesh is not None:
        from twin.sim.scene import foam_mesh

        foam = mesh_object(args.object_mesh, LIBRARY["block"], args.mesh_scale)
        foam_mesh(foam)  # a bad mesh fails here, in one line
        return foam
    if args.shape is not None:
        size = tuple(s / 1e3 for s in args.size_mm)
        return LIBRARY["block"].with_overrides(name=args.shape, shape=args.shape, size_m=size)
    if (metadata.get("object") or {}).get("shape"):
        return None  # the run's own record (twin.sim.modulus reads it)
    raise ConfigError(
        f"{args.run_dir}: the run does not describe its object; give --shape and --size-mm, or --object-mesh"
    )


def cmd_identify(args: argparse.Namespace) -> int:
    """`twin identify`: eq. 4 per finger, the modulus, and the files that show them."""
    if (args.shape is None) != (args.size_mm is None):
        raise ConfigError("--shape and --size-mm go together")
    if args.object_mesh is not None and args.shape is not None:
        raise ConfigError("--object-mesh or --shape/--size-mm, not both")
    from twin.sim.modulus import Tolerances

    stated = {
        "placement_m": None if args.placement_tolerance_mm is None else args.placement_tolerance_mm / 1e3,
        "size_m": None if args.size_tolerance_mm is None else args.size_tolerance_mm / 1e3,
        "poisson": None if args.poisson is None else tuple(args.poisson),
    }
    args.tolerances = Tolerances(**{k: v for k, v in stated.items() if v is not None})
    metadata = run_metadata(args.run_dir, "RUN")
    if args.free is not None:
        name = experiment_name(run_metadata(args.free, "--free"))
        if name != "free":
            raise ConfigError(
                f"--free {args.free}: a '{name}' run, not a `twin run free` run (the hand's own terms come "
                "from the empty hand swinging its fingers)"
            )
    description = _described_object(args, metadata)
    check_writable(args.out or args.run_dir / "identify")  # every input checked; before minutes of computing
    from twin.identify.identify import identify_run
    from twin.identify.report import FigureProcess, poisson_line, write_results
    from twin.sim.modulus import ImpreciseEstimateError

    ident = identify_run(args.run_dir, args.free, args.model)  # eq. 4: quick, and it fails early
    out = args.out or args.run_dir / "identify"
    poisson = _poisson(args, description, ident.notes)
    try:
        estimate = _estimate_modulus(args, description)
    except ImpreciseEstimateError as exc:  # the interval alone, and why: written down, then the one line
        ident.material = exc.estimate.to_json() | {"number_given": False, "why": str(exc), "poisson": poisson}
        with FigureProcess() as figure_process:
            write_results(ident, out, figure_process)
        raise ImpreciseEstimateError(f"{exc} (the interval is in {out})", exc.estimate) from None
    ident.material = estimate.to_json() | {"number_given": True, "poisson": poisson}
    with FigureProcess() as figure_process:
        paths = write_results(ident, out, figure_process)
    if args.json:
        print(paths["results"].read_text(), end="")
        return 0
    for f in ident.fingers:
        p = f.fit.params
        model = ", ".join(f"{k} {v:.4g}" for k, v in p.items())
        print(
            f"F{f.finger}: {model}  (R^2 {f.fit.r2:.3f}, rms {f.fit.rms_n:.2f} N); "
            f"secant {f.secant_n_m:.0f} N/m; "
            f"moment arm {f.moment_arm_m * 1e3:.1f} mm; eq. 4 residual {f.eq4_residual_rms_nm:.3f} N*m"
        )
    print(f"grip: {ident.grip[0]:.4f} +- {ident.grip[1]:.4f} N*m per 1000 counts (gauges against drives)")
    low, high = (v / 1e3 for v in estimate.ci95_pa)
    line = f"E = {estimate.young_pa / 1e3:.2f} kPa  (95 % {low:.2f}-{high:.2f} kPa)"
    if estimate.twin_young_pa is not None:
        error = estimate.young_pa / estimate.twin_young_pa - 1
        line += f"; the twin's E {estimate.twin_young_pa / 1e3:.2f} kPa, error {100 * error:+.1f} %"
    print(line)
    print(poisson_line(poisson))
    widths = ", ".join(f"{k} {100 * v:.1f} %" for k, v in estimate.sigma_log.items() if k != "total")
    print(
        f"  from the squeeze stiffness {estimate.stiffness_n_m:.0f} N/m over {estimate.cycles} cycles and "
        f"{len(estimate.simulations)} simulations of the procedure; 1-sigma: {widths}"
    )
    if estimate.width_sources:
        parts = ", ".join(f"{k} {100 * v:.0f} %" for k, v in estimate.width_sources.items())
        print(f"  the nuisance's variance from: {parts}")
    for note in ident.notes:
        print(f"note: {note}")
    print(f"wrote {paths['results']}, {paths['figure'].name}, {paths['rerun'].name}")
    return 0


CAMERAS_WOULD_ADD = (
    "two opposite stereo pairs (`twin run compress --cameras --camera-placement lateral,opposite`) would "
    "measure it: +-0.04-0.05 (95 %) on held-out runs of the fast block and cylinder (BENCHMARKS.md)"
)


def _poisson(args: argparse.Namespace, description, notes: list[str]) -> dict:  # noqa: ANN001
    """nu for the results file: read from the run's two opposite stereo pairs where it has them
    (twin.sim.poisson.read_run); with --poisson-from-cameras it narrows the Poisson ratios the modulus
    simulations draw (args.tolerances) to its 95 % interval within the tolerated range. Opt-in: on the
    hidden draw 2043 (benchmarks/identification_cameras.py) it read nu on 21 of 39 runs, narrowed the draw
    on 9 and gave no more numbers than the tolerated range on the runs both were scored on. Without the
    pairs: the tolerated range, and what the cameras would add."""
    from dataclasses import replace

    from twin.sim.poisson import NO_PAIRS, REFERENCE_CAVEAT, poisson_for_modulus

    tolerated = args.tolerances.poisson
    unmeasured = {
        "poisson_ci95": list(tolerated),
        "source": "the tolerated range (--poisson), drawn in every simulation: not measured",
        "cameras_would_add": CAMERAS_WOULD_ADD,
    }
    said = poisson_for_modulus(
        args.run_dir,
        description,
        tolerated,
        narrow=args.poisson_from_cameras,
        announce=None if args.no_progress else lambda message: print(message, file=sys.stderr),
    )
    if said.read is None:
        if said.failed != NO_PAIRS:
            notes.append(
                f"the two stereo pairs could not read the Poisson ratio ({said.failed}): the tolerated range "
                "is drawn"
            )
        return unmeasured
    read = said.read
    (low, high), beyond = read.poisson_95_simulated()
    if not args.poisson_from_cameras:  # reported, not drawn (opt-in: see the docstring)
        notes.append(
            f"the two stereo pairs read nu {read.poisson:.3f} ({low:.3f}-{high:.3f}, 95 %"
            f"{', cut to the Poisson ratios simulated' if beyond else ''}); the modulus simulations still "
            f"draw the tolerated {tolerated[0]:g}-{tolerated[1]:g} (--poisson-from-cameras draws within "
            f"the reading); {REFERENCE_CAVEAT}"
        )
        return read.to_json() | {"drawn_range": list(tolerated), "narrowed": False}
    notes.append(f"the two stereo pairs read nu {read.poisson:.3f}: {REFERENCE_CAVEAT}")
    if said.note:
        notes.append(said.note)
    args.tolerances = replace(args.tolerances, poisson=said.drawn)
    return read.to_json() | {"drawn_range": list(said.drawn), "narrowed": True}


def _estimate_modulus(args: argparse.Namespace, description):  # noqa: ANN001
    """twin.sim.modulus.estimate_modulus with a progress bar (simulations done of those planned)."""
    from twin.sim.modulus import estimate_modulus

    precision = args.precision / 100
    if args.no_progress:
        return estimate_modulus(
            args.run_dir,
            description=description,
            workers=args.workers,
            precision=precision,
            tolerances=args.tolerances,
        )
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    columns = (TextColumn("[bold]modulus"), BarColumn(), MofNCompleteColumn(), TextColumn("simulations"))
    with Progress(*columns, TimeElapsedColumn(), transient=True) as bar:
        task = bar.add_task("simulations", total=None)

        def progress(done: int, planned: int) -> None:
            bar.update(task, completed=done, total=planned)

        return estimate_modulus(
            args.run_dir,
            description=description,
            workers=args.workers,
            progress=progress,
            precision=precision,
            tolerances=args.tolerances,
        )


command = cmd_identify
