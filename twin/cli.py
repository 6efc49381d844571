"""The `twin` command line: objects, run, identify, fit, sweep, train, calibrate, emulate, info, compare,
view.

Bad input ends with one line on stderr and exit status 2; nothing is simulated or written first.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from twin.interface.errors import ConfigError, TwinError
from twin.validation import (
    check_run_metadata,
    duration,
    existing_dir,
    existing_file,
    experiment_name,
    finite,
    integer,
    new_dir,
    out_dir,
    out_file,
    run_dir,
    seed,
)

if TYPE_CHECKING:
    from twin.shape.dataset import ShapeData

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
"""128 + SIGINT, as a shell reports a Ctrl-C; SIGTERM is treated the same."""


def _fail(message: str) -> int:
    print(f"twin: error: {message}", file=sys.stderr)
    return EXIT_USAGE


class TwinArgumentParser(argparse.ArgumentParser):
    """argparse with the house's error form: one line `twin: error: ...` on stderr and exit status 2
    (argparse's own prints the usage first: two lines or more)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        """One line naming the subcommand's help, then exit 2."""
        line = " ".join(message.split())
        self.exit(EXIT_USAGE, f"twin: error: {line} (see `{self.prog} --help`)\n")

    def _get_values(self, action: argparse.Action, arg_strings: list[str]) -> object:
        """argparse's, less a hole: before Python 3.12 `--duration=--` gave the flag [] unchecked."""
        value = super()._get_values(action, arg_strings)
        if action.nargs is None and isinstance(value, list):
            self.error(f"argument {argparse._get_action_name(action)}: expected one argument")
        return value


YOUNG_PA = finite(0, 1e9, min_inclusive=False)
"""Young's modulus (Pa): > 0, and no stiffer than 1 GPa (a foam twin; MuJoCo diverges long before)."""
SIZE_MM = finite(0, 1000, min_inclusive=False)
"""An object's extent (mm): > 0 and at most 1 m."""
WORKERS = integer(1, 1024)
"""Processes in parallel."""


def _add_foam_overrides(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("object overrides (any library parameter)")
    g.add_argument("--young", type=YOUNG_PA, metavar="PA", help="Young's modulus (Pa)")
    g.add_argument(
        "--poisson", type=finite(0, 0.5, max_inclusive=False), metavar="NU", help="Poisson ratio, in [0, 0.5)"
    )
    g.add_argument("--damping", type=finite(0, 1), metavar="S", help="elasticity damping (s), in [0, 1]")
    g.add_argument("--density", type=finite(1, 2e4), metavar="KG_M3", help="density (kg/m^3; foams: 10-100)")
    g.add_argument("--size-mm", type=SIZE_MM, nargs=3, metavar=("X", "Y", "Z"), help="extents (mm)")
    g.add_argument(
        "--placement-mm",
        type=finite(-10, 10),
        nargs=2,
        metavar=("X", "Y"),
        help="where the object's centre sits off the palm's centre (mm, hand frame), each within 10 mm",
    )
    g.add_argument(
        "--fidelity",
        choices=("fast", "faithful"),
        help="foam discretization preset: fast (8 trilinear nodes) or faithful (a volumetric mesh)",
    )
    g.add_argument(
        "--resolution",
        type=integer(3, 12),
        metavar="N",
        help="foam vertices per axis (fast) or along the longest extent (faithful), 3-12",
    )
    g.add_argument("--dof", choices=("trilinear", "quadratic", "full"), help="MuJoCo flex dof")
    g.add_argument(
        "--friction", type=finite(0, 3, min_inclusive=False), help="sliding friction coefficient, in (0, 3]"
    )


def _add_mesh_scale(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--mesh-scale",
        type=finite(1e-6, 1, min_inclusive=True),
        default=0.001,
        metavar="M",
        help="metres per --object-mesh unit (default 0.001: the file is in millimetres)",
    )


def _add_run_options(p: argparse.ArgumentParser, duration_s: float) -> None:
    """What every `twin run` experiment takes: backend, hand, rig, duration, seed, output, progress."""
    p.add_argument("--backend", choices=("sim", "hardware"), default="sim")
    p.add_argument("--hand", metavar="PORT", help="hardware: the hand's port or URL (overrides --rig)")
    p.add_argument(
        "--rig", type=existing_file(), metavar="FILE", help="hardware: rig.toml (ports, baud, limits)"
    )
    p.add_argument(
        "--duration", type=duration(), default=duration_s, metavar="S", help="run length (s), up to a day"
    )
    p.add_argument("--seed", type=seed(), default=0, help="seed of the sensor noise (sim), 0 to 2^32-1")
    p.add_argument("--out", type=new_dir(), metavar="DIR", help="run directory (default runs/...)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `twin`."""
    parser = TwinArgumentParser(
        prog="twin",
        description="Barrett BH8 digital twin: simulate, record and view foam compression runs; identify the "
        "foam (eq. 4), fit the twin to a run, and train the shape network.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("objects", help="list the foam library")
    p.add_argument("--json", action="store_true", help="print a JSON list of objects")

    p = sub.add_parser("run", help="run an experiment")
    run_sub = p.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    c = run_sub.add_parser("compress", help="grasp, balance, then periodic compression (paper §6.2)")
    c.add_argument("--object", default="block", help="library object (see `twin objects`)")
    c.add_argument(
        "--object-mesh",
        type=existing_file(),
        metavar="FILE",
        help="a foam of any closed shape: an .stl/.obj surface (e.g. a scan), with --object's material",
    )
    _add_mesh_scale(c)
    _add_run_options(c, duration_s=10.0)
    c.add_argument(
        "--cameras", action="store_true", help="sample the stereo pair at 30 fps and reconstruct the foam"
    )
    c.add_argument(
        "--render-native",
        action="store_true",
        help="sim cameras: render at 640x480 and scale to 320x240 (slower) instead of at 320x240",
    )
    c.add_argument(
        "--stereo-calibration",
        type=existing_file(),
        metavar="FILE",
        help="cameras: calibration file (`twin calibrate cameras`; default: sim truth, rig.toml on hardware)",
    )
    c.add_argument(
        "--bbox",
        metavar="X,Y,W,H",
        help="cameras: the object's box on the first frame, rectified left pixels (sim default: the foam's)",
    )
    c.add_argument(
        "--predict",
        type=existing_dir(),
        metavar="MODEL",
        help="a `twin train` model: predict the object's contour from every hand reading (with --cameras, "
        "beside the measured one)",
    )
    _add_foam_overrides(c)

    f = run_sub.add_parser("free", help="swing the empty hand's fingers (identifies eq. 4's hand terms)")
    _add_run_options(f, duration_s=20.0)

    p = sub.add_parser(
        "identify", help="eq. 4 per finger and the foam's Young's modulus, from a compress run"
    )
    p.add_argument("run_dir", type=run_dir(), metavar="RUN", help="a `twin run compress` run directory")
    p.add_argument(
        "--free", type=run_dir(), metavar="FREE_RUN", help="a `twin run free` run: the hand's own terms"
    )
    p.add_argument("--model", choices=("kelvin-voigt", "hunt-crossley"), default="kelvin-voigt")
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
    _add_mesh_scale(p)
    p.add_argument("--workers", type=WORKERS, default=2, help="simulations in parallel (processes)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")

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

    p = sub.add_parser(
        "sweep", help="shape-network dataset: many compressions with varied finger trajectories"
    )
    p.add_argument("--objects", nargs="+", default=["sphere"], metavar="NAME", help="library objects")
    p.add_argument(
        "--trajectories", type=integer(1, 100_000), default=16, metavar="N", help="trajectories per object"
    )
    p.add_argument("--workers", type=WORKERS, default=2, metavar="K", help="trajectories run in parallel")
    p.add_argument("--executor", choices=("local", "ray"), default="local")
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
    p.add_argument("--seed", type=seed(), default=0)
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
    p.add_argument("--epochs", type=integer(1, 10_000_000), default=3000)
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
    p.add_argument("--seed", type=seed(), default=0)
    p.add_argument("--json", action="store_true", help="print the evaluation as JSON")

    p = sub.add_parser("emulate", help="serve emulated devices backed by the twin")
    p.add_argument("what", choices=("hand", "rig"), help="hand: the BH8-262; rig: every emulated device")
    p.add_argument(
        "--baud",
        type=integer(1, 10_000_000),
        default=9600,
        help="rate the hand powers up at (default 9600; the BH8-262's rates: 600 to 38400)",
    )
    p.add_argument("--port", default="pty", metavar="pty|tcp:PORT", help="where to serve (default pty)")
    p.add_argument("--faults", metavar="SPEC", help="hand faults, e.g. garbage@40,drop@80,vanish@200")
    p.add_argument("--tactile-faults", metavar="SPEC", help="rig: tactile faults, e.g. corrupt@30,stall@60:1")
    p.add_argument("--object", default="block", help="library object in the twin's hand ('none': empty)")
    p.add_argument("--seed", type=seed(), default=0, help="seed of the twin's sensor noise")
    p.add_argument(
        "--rig-file", type=out_file(), metavar="FILE", help="write a rig.toml pointing here (rig: always)"
    )
    p.add_argument(
        "--duration", type=duration(), metavar="S", help="stop after S seconds, up to a day (default: Ctrl-C)"
    )
    p.add_argument(
        "--no-cameras", action="store_true", help="rig: leave the stereo cameras out (they cost CPU)"
    )

    p = sub.add_parser("info", help="summarize a run directory")
    p.add_argument("run_dir", type=run_dir(), metavar="DIR")
    p.add_argument("--json", action="store_true")

    p = sub.add_parser("compare", help="compare two runs of one scenario (e.g. sim vs hardware)")
    p.add_argument("run_a", type=run_dir(), metavar="DIR_A", help="reference run (e.g. the sim backend's)")
    p.add_argument("run_b", type=run_dir(), metavar="DIR_B")
    p.add_argument("--json", action="store_true")

    p = sub.add_parser("view", help="open a run in the Rerun viewer")
    p.add_argument("run_dir", type=existing_dir(), metavar="DIR")

    p = sub.add_parser("calibrate", help="calibrate a sensor")
    cal_sub = p.add_subparsers(dest="what", required=True, metavar="WHAT")
    c = cal_sub.add_parser("cameras", help="stereo pair + camera-to-hand transform (paper §4.1)")
    c.add_argument(
        "--out",
        type=out_file(),
        default=Path("stereo_calibration.json"),
        metavar="FILE",
        help="calibration file (an existing one only with --force)",
    )
    c.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    c.add_argument(
        "--views",
        type=existing_dir(),
        metavar="DIR",
        help="from image pairs: left_*.png/right_*.png chessboards, palm_left/right.png (default: sim)",
    )
    c.add_argument(
        "--seed", type=seed(), help="sim: seed of the chessboard poses and camera noise (default 0)"
    )
    return parser


def cmd_objects(args: argparse.Namespace) -> int:
    """`twin objects`: the foam library."""
    from twin.sim.foam import LIBRARY

    if args.json:
        print(json.dumps([p.to_json() for p in LIBRARY.values()], indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="Foam library")
    for col in ("name", "shape", "size (mm)", "E (kPa)", "nu", "class", "density", "mass (g)", "fidelity"):
        table.add_column(col)
    for p in LIBRARY.values():
        table.add_row(
            p.name,
            p.shape,
            " x ".join(f"{s * 1e3:.0f}" for s in p.size_m),
            f"{p.young_pa / 1e3:g}",
            f"{p.poisson:g}",
            p.stiffness_class,
            f"{p.density_kg_m3:g}",
            f"{p.mass_kg * 1e3:.1f}",
            p.fidelity,
        )
    Console().print(table)
    return 0


def _foam_from_args(args: argparse.Namespace):
    from twin.sim.foam import get_object, mesh_object

    size = tuple(s / 1e3 for s in args.size_mm) if args.size_mm else None
    placement = tuple(v / 1e3 for v in args.placement_mm) if args.placement_mm else None
    base = get_object(args.object)
    if getattr(args, "object_mesh", None) is not None:
        if size is not None:
            raise ConfigError("--size-mm does not apply to --object-mesh (the mesh gives the size)")
        from twin.sim.scene import foam_mesh

        foam = mesh_object(args.object_mesh, base, args.mesh_scale).with_overrides(
            young_pa=args.young, poisson=args.poisson, damping=args.damping,
            density_kg_m3=args.density, fidelity=args.fidelity, resolution=args.resolution,
            dof=args.dof, friction=args.friction, placement_m=placement,
        )  # fmt: skip
        foam_mesh(foam)  # tetrahedralise now: a bad mesh fails in one line before anything is written
        return foam
    return base.with_overrides(
        young_pa=args.young,
        poisson=args.poisson,
        damping=args.damping,
        density_kg_m3=args.density,
        size_m=size,
        fidelity=args.fidelity,
        resolution=args.resolution,
        dof=args.dof,
        friction=args.friction,
        placement_m=placement,
    )


def cmd_run_compress(args: argparse.Namespace) -> int:
    """`twin run compress`: validate, run, report."""
    from experiments.compress import run_compress
    from twin.session import default_run_dir

    foam = _foam_from_args(args)
    run_dir = args.out or default_run_dir("compress", foam.name)
    shape_model = None
    if args.predict is not None:
        from twin.shape.model import ShapeModel

        try:
            shape_model = ShapeModel.load(args.predict)
        except ValueError as exc:
            raise ConfigError(f"--predict {exc}") from None
        if shape_model.target == "surface":
            raise ConfigError("--predict: a surface model (--target surface); live prediction takes contours")
        trained_on = shape_model.metadata.get("object")
        if trained_on and trained_on != foam.name:
            raise ConfigError(
                f"--predict: the model was trained on '{trained_on}', the hand holds '{foam.name}'"
            )
    box = None
    if (args.bbox is not None or args.stereo_calibration is not None) and not args.cameras:
        raise ConfigError("--bbox and --stereo-calibration need --cameras")
    if args.bbox is not None:
        from twin.vision.pipeline import parse_box

        box = parse_box(args.bbox)
    if args.backend == "sim":
        if args.hand or args.rig:
            raise ConfigError("--hand and --rig need --backend hardware")
        from twin.sim.backend import SimBackend

        backend = SimBackend(
            foam,
            seed=args.seed,
            stereo=args.cameras,
            stereo_render_native=args.render_native,
            stereo_calibration_file=args.stereo_calibration,
        )
    else:
        from hardware.backend import HardwareBackend
        from hardware.rig_config import RigConfig, load_rig

        rig = load_rig(args.rig) if args.rig else RigConfig()
        if args.hand:
            rig = rig.with_hand_port(args.hand)
        if args.stereo_calibration is not None:
            raise ConfigError("--stereo-calibration is for the sim; on hardware set calibration in [stereo]")
        backend = HardwareBackend(rig)
        if args.cameras and backend.stereo is None:
            raise ConfigError("--cameras: the rig has no cameras (add a [stereo] section to rig.toml)")
        if not args.cameras:
            backend.stereo = None  # cameras configured but not asked for: the run leaves them closed
    outcome = _with_progress(
        args.duration,
        not args.no_progress,
        lambda progress: run_compress(
            backend,
            run_dir,
            duration_s=args.duration,
            object_name=foam.name,
            progress=progress,
            stereo_box=box,
            shape_model=shape_model,
        ),
    )
    truth = _print_completion(outcome).get("stereo_truth")
    if truth:
        print(f"reconstruction vs the twin's truth: {_surface_summary(truth)}")
    print(f"view it: twin view {outcome.run_dir}")
    return 0


def _print_completion(outcome) -> dict:  # noqa: ANN001 - twin.session.RunOutcome, imported lazily
    """'run complete' on stdout; on stderr each of the run's warnings (a loop that missed its rate) and
    how many hand cycles the driver recovered (each is listed in run.json). Returns run.json's metadata."""
    print(f"run complete: {outcome.run_dir}  ({outcome.result.samples.get('hand', 0)} hand samples)")
    for warning in outcome.warnings:
        print(f"twin: warning: {warning}", file=sys.stderr)
    meta = json.loads((outcome.run_dir / "run.json").read_text())["metadata"]
    recoveries = meta.get("hand_recoveries") or []
    if recoveries:
        print(
            f"twin: warning: the hand driver recovered {len(recoveries)} cycle(s) "
            f"(run.json: metadata.hand_recoveries); first: {recoveries[0]}",
            file=sys.stderr,
        )
    return meta


def _hand_backend(args: argparse.Namespace, foam):  # noqa: ANN001
    """The backend of a run without cameras: the twin with `foam`, or the rig's hardware."""
    if args.backend == "sim":
        if args.hand or args.rig:
            raise ConfigError("--hand and --rig need --backend hardware")
        from twin.sim.backend import SimBackend

        return SimBackend(foam, seed=args.seed)
    from hardware.backend import HardwareBackend
    from hardware.rig_config import RigConfig, load_rig

    rig = load_rig(args.rig) if args.rig else RigConfig()
    if args.hand:
        rig = rig.with_hand_port(args.hand)
    backend = HardwareBackend(rig)
    backend.stereo = None
    return backend


def cmd_run_free(args: argparse.Namespace) -> int:
    """`twin run free`: the empty hand swings its fingers (eq. 4's hand terms)."""
    from experiments.free_motion import run_free_motion
    from twin.session import default_run_dir

    run_dir = args.out or default_run_dir("free", "none")
    backend = _hand_backend(args, None)
    outcome = _with_progress(
        args.duration,
        not args.no_progress,
        lambda progress: run_free_motion(backend, run_dir, duration_s=args.duration, progress=progress),
    )
    _print_completion(outcome)
    print(f"use it: twin identify RUN --free {outcome.run_dir}")
    return 0


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
    metadata = _run_metadata(args.run_dir, "RUN")
    if args.free is not None:
        name = experiment_name(_run_metadata(args.free, "--free"))
        if name != "free":
            raise ConfigError(
                f"--free {args.free}: a '{name}' run, not a `twin run free` run (the hand's own terms come "
                "from the empty hand swinging its fingers)"
            )
    description = _described_object(args, metadata)
    from twin.identify.identify import identify_run
    from twin.identify.report import FigureProcess, write_results

    ident = identify_run(args.run_dir, args.free, args.model)  # eq. 4: quick, and it fails early
    estimate = _estimate_modulus(args, description)
    ident.material = estimate.to_json()
    with FigureProcess() as figure_process:
        paths = write_results(ident, args.out or args.run_dir / "identify", figure_process)
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
    widths = ", ".join(f"{k} {100 * v:.1f} %" for k, v in estimate.sigma_log.items() if k != "total")
    print(
        f"  from the squeeze stiffness {estimate.stiffness_n_m:.0f} N/m over {estimate.cycles} cycles and "
        f"{len(estimate.simulations)} simulations of the procedure; 1-sigma: {widths}"
    )
    for note in ident.notes:
        print(f"note: {note}")
    print(f"wrote {paths['results']}, {paths['figure'].name}, {paths['rerun'].name}")
    return 0


def _estimate_modulus(args: argparse.Namespace, description):  # noqa: ANN001
    """twin.sim.modulus.estimate_modulus with a progress bar (simulations done of those planned)."""
    from twin.sim.modulus import estimate_modulus

    if args.no_progress:
        return estimate_modulus(args.run_dir, description=description, workers=args.workers)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    columns = (TextColumn("[bold]modulus"), BarColumn(), MofNCompleteColumn(), TextColumn("simulations"))
    with Progress(*columns, TimeElapsedColumn(), transient=True) as bar:
        task = bar.add_task("simulations", total=None)

        def progress(done: int, planned: int) -> None:
            bar.update(task, completed=done, total=planned)

        return estimate_modulus(
            args.run_dir, description=description, workers=args.workers, progress=progress
        )


def _run_metadata(path: Path, flag: str) -> dict:
    """run.json's metadata, with the types the analyses read; one line naming the file and key if not."""
    run_json = path / "run.json"
    try:
        info = json.loads(run_json.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"{flag} {path}: run.json is unreadable ({exc})") from None
    return check_run_metadata(info, run_json)


def cmd_fit(args: argparse.Namespace) -> int:
    """`twin fit`: the twin's foam parameters that reproduce a run, and the files that show them."""
    if args.size_mm is not None and args.object is None:
        raise ConfigError("--size-mm needs --object (the library object it resizes)")
    _run_metadata(args.run_dir, "RUN")
    foam = None
    if args.object is not None:
        from twin.sim.foam import get_object

        size = tuple(s / 1e3 for s in args.size_mm) if args.size_mm else None
        foam = get_object(args.object).with_overrides(size_m=size)  # unknown or ill-fitting: one line
    from twin.sim.fit import fit_run
    from twin.sim.fit_report import write_fit

    def progress(replays: int, wall_s: float) -> None:
        if not args.no_progress:
            print(f"\r  {replays} replays, {wall_s:.0f} s", end="", file=sys.stderr, flush=True)

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


def cmd_sweep(args: argparse.Namespace) -> int:
    """`twin sweep`: run (or resume) a dataset of trajectories, with a progress bar."""
    from experiments.sweep import check_ray_address, draw_trajectories, sweep, trajectory_from_run
    from twin.sim.foam import get_object

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


def cmd_train(args: argparse.Namespace) -> int:
    """`twin train`: the network and its baselines on held-out trajectories."""
    from twin.shape.dataset import DEFAULT_TARGET, load_dataset
    from twin.shape.train import FOLDS, train

    if args.folds is not None and args.validation is not None:
        raise ConfigError("--folds and --validation: choose one way to hold trajectories out")
    metadata = {
        "object": args.object,
        "target": args.target,
        "dataset": str(args.dataset),
        "inputs": ["p1", "p2", "p3", "T1", "T2", "T3"],
    }
    name = args.object if args.target == DEFAULT_TARGET else f"{args.object}-{args.target}"
    out_dir = args.out or args.dataset / "models" / name
    if args.target == "surface":
        if args.folds is not None:
            raise ConfigError("--folds: the 3-D variant is scored on one held-out split (--validation F)")
        return _train_surface(args, metadata, out_dir)
    data = load_dataset(args.dataset, args.object, args.target)
    if args.validation is None:  # by default 4 folds, or one per trajectory where there are fewer
        folds = min(FOLDS, len(set(data.trajectory.tolist()))) if args.folds is None else args.folds
        return _cross_validate(args, data, metadata, out_dir, folds)
    result = train(
        data, validation_fraction=args.validation, seed=args.seed, epochs=args.epochs, metadata=metadata
    )
    out = result.model.save(out_dir)
    report = {
        "model": str(out),
        "train_samples": result.train_samples,
        "validation_samples": result.validation_samples,
        "validation_trajectories": result.validation_trajectories,
        "wall_s": result.wall_s,
        "held_out": _held_out_rows(result.evaluations),
    }
    if _write_report(out, report, args.json):
        return 0
    print(f"{result.train_samples} training samples; held out trajectories {result.validation_trajectories}")
    _print_evaluations(result.evaluations)
    print(f"wrote {out}")
    return 0


def _cross_validate(
    args: argparse.Namespace, data: ShapeData, metadata: dict, out_dir: Path, folds: int
) -> int:
    """`twin train` by K-fold cross-validation: every trajectory held out once; the model kept is
    trained on all of them."""
    from rich.console import Console
    from rich.progress import Progress

    from twin.shape.train import NETWORK, cross_validate, fold_groups

    fold_groups(data, folds, args.seed)  # a bad --folds fails here, in one line, before the bar
    with Progress(console=Console(stderr=True), transient=True, disable=args.json) as bar:
        task = bar.add_task(f"networks ({folds} folds, then all trajectories)", total=folds + 1)
        result = cross_validate(
            data,
            folds=folds,
            seed=args.seed,
            epochs=args.epochs,
            metadata=metadata,
            progress=lambda done, _total: bar.update(task, completed=done),
        )
    out = result.model.save(out_dir)
    report = {
        "model": str(out),
        "samples": result.samples,
        "folds": result.folds,
        "wall_s": result.wall_s,
        "held_out": _held_out_rows(result.evaluations),
        "fold_errors_px": result.fold_errors_px,
        "trajectory_errors_px": {str(k): v for k, v in result.trajectory_errors_px.items()},
    }
    if _write_report(out, report, args.json):
        return 0
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
    print(f"wrote {out} (trained on every trajectory)")
    return 0


def _write_report(model_dir: Path, report: object, as_json: bool) -> bool:
    """evaluation.json beside the model; with --json also printed, and then nothing else is (True)."""
    text = json.dumps(report, indent=1)
    (model_dir / "evaluation.json").write_text(text)
    if as_json:
        print(text)
    return as_json


def _held_out_rows(evaluations: list) -> list[dict]:
    """Each predictor's held-out errors, as evaluation.json keeps them."""
    return [
        {
            "predictor": e.name,
            "error_px": e.error_px,
            "error_mm": e.error_mm,
            "error_px_vs_smoothed": e.error_px_smoothed,
        }
        for e in evaluations
    ]


def _print_evaluations(evaluations: list) -> None:
    for e in evaluations:
        print(
            f"  {e.name:28s} {e.error_px:6.2f} px  {e.error_mm:6.2f} mm  "
            f"({e.error_px_smoothed:.2f} px vs smoothed contours)"
        )


def _train_surface(args: argparse.Namespace, metadata: dict, out_dir: Path) -> int:
    """`twin train --target surface`: the 3-D variant and its baselines, heights in mm."""
    from twin.shape.dataset import load_surface_dataset
    from twin.shape.surface_train import train_surface

    data = load_surface_dataset(args.dataset, args.object)
    result = train_surface(
        data,
        validation_fraction=0.25 if args.validation is None else args.validation,
        seed=args.seed,
        epochs=args.epochs,
        metadata=metadata,
    )
    out = result.model.save(out_dir)
    report = {
        "model": str(out),
        "train_samples": result.train_samples,
        "validation_samples": result.validation_samples,
        "validation_trajectories": result.validation_trajectories,
        "modelled_cells": result.modelled_cells,
        "observed_fraction": result.observed_fraction,
        "measured_vs_truth_mm": result.measured_truth_error_mm,
        "wall_s": result.wall_s,
        "held_out": [
            {"predictor": e.name, "error_mm": e.error_mm, "error_mm_vs_truth": e.truth_error_mm}
            for e in result.evaluations
        ],
    }
    if _write_report(out, _nan_to_null(report), args.json):
        return 0
    print(f"{result.train_samples} training samples; held out trajectories {result.validation_trajectories}")
    print(
        f"  {result.modelled_cells} grid cells modelled; {100 * result.observed_fraction:.0f} % of held-out "
        f"cells observed; measured heights vs the true surface: {result.measured_truth_error_mm:.2f} mm"
    )
    for e in result.evaluations:
        print(f"  {e.name:28s} {e.error_mm:6.2f} mm vs measured  {e.truth_error_mm:6.2f} mm vs true surface")
    print(f"wrote {out}")
    return 0


def _nan_to_null(value: object) -> object:
    """A report with NaN floats as None (strict JSON)."""
    if isinstance(value, dict):
        return {k: _nan_to_null(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_nan_to_null(v) for v in value]
    if isinstance(value, float) and value != value:
        return None
    return value


def _surface_summary(truth: dict) -> str:
    """One line: a run's reconstruction accuracy against the twin's truth."""
    return (
        f"median {truth['median_mm']:.2f} mm (worst frame {truth['worst_median_mm']:.2f}), "
        f"coverage {100 * truth['coverage']:.0f} % (worst {100 * truth['worst_coverage']:.0f} %), "
        f"{100 * truth['frames_within_targets']:.0f} % of {truth['frames']} frames within "
        f"{truth['targets']['median_mm']:g} mm / {100 * truth['targets']['coverage']:.0f} %"
    )


def _with_progress(duration_s: float, show: bool, job):  # noqa: ANN001
    if not show:
        return job(None)
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.1f}/{task.total:.1f} s"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, transient=False) as bar:
        task = bar.add_task("run time", total=duration_s)
        return job(lambda t_s: bar.update(task, completed=min(t_s, duration_s)))


def cmd_emulate(args: argparse.Namespace) -> int:
    """`twin emulate hand|rig`: serve the twin-backed emulators until Ctrl-C (or --duration)."""
    import time

    from hardware.bh262.driver import SUPPORTED_BAUD

    if args.baud not in SUPPORTED_BAUD:
        raise ConfigError(f"--baud {args.baud}: not one of {', '.join(map(str, SUPPORTED_BAUD))}")
    where = args.port
    if where != "pty" and not (
        where.startswith("tcp:") and where[4:].isascii() and where[4:].isdigit() and int(where[4:]) < 65536
    ):
        raise ConfigError(f"--port {where!r}: expected pty or tcp:PORT (tcp:0 picks a free port)")
    from hardware.bh262.emulator import make_hand_emulator
    from hardware.rig_config import rig_toml
    from hardware.rig_emulator import RigEmulator
    from twin.sim.foam import get_object

    object_name = None if args.object == "none" else args.object
    if object_name:
        get_object(object_name)  # unknown names fail here, in one line

    def event(message: str) -> None:
        print(f"[emulator] {message}", flush=True)

    if args.what == "hand":
        emulator = make_hand_emulator(
            object_name, baud=args.baud, faults=args.faults, seed=args.seed, on_event=event
        )
    else:
        emulator = RigEmulator(
            object_name,
            baud=args.baud,
            faults=args.faults,
            tactile_faults=args.tactile_faults,
            seed=args.seed,
            on_event=event,
            cameras=not args.no_cameras,
        )
    try:
        if args.what == "hand":
            address = emulator.serve_pty() if where == "pty" else emulator.serve_tcp(int(where[4:]))
        else:
            address, tactile_address = emulator.serve(where)
    except OSError as exc:
        emulator.close()
        raise ConfigError(f"--port {where}: {exc.strerror or exc}") from None
    print(f"hand: {address}  (BH8-262 at {args.baud} baud, object: {args.object})", flush=True)
    if args.what == "rig":
        print(f"tactile: {tactile_address}  (PPS pads, 162 taxels at 30 Hz)", flush=True)
        if emulator.camera_addresses is None:
            print("cameras: not emulated (--no-cameras)", flush=True)
        else:
            left, right = emulator.camera_addresses
            rate = emulator.cameras.rate_hz
            print(f"cameras: {left}  {right}  (MJPEG over HTTP, 320x240 at {rate:g} fps)", flush=True)
        print(f"rig file: {emulator.write_rig_file(args.rig_file)}", flush=True)
    elif args.rig_file:
        args.rig_file.write_text(rig_toml(address, baud=args.baud))
        print(f"rig file: {args.rig_file}", flush=True)
    print("ready; Ctrl-C stops", flush=True)
    deadline = time.monotonic() + args.duration if args.duration else float("inf")
    try:
        while time.monotonic() < deadline:
            time.sleep(0.1)
            if emulator.failed():  # a serving thread died: say so and exit, never idle as if "ready"
                from twin.interface.errors import DeviceError

                raise DeviceError(f"the emulator stopped serving: {emulator.failed()}")
    except KeyboardInterrupt:
        pass
    finally:
        emulator.close()
    print("emulator stopped", flush=True)
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    """`twin info DIR`: streams, sample counts, rates, duration, metadata."""
    from twin.recording import open_run

    run = open_run(args.run_dir)
    meta = check_run_metadata(run.info, run.path / "run.json")
    summary = run.summary()
    differ = [
        {"stream": name, "readable": readable, "recorded": recorded}
        for name, (recorded, readable) in run.sample_mismatches().items()
    ]
    if args.json:
        print(
            json.dumps(
                {
                    "path": str(run.path),
                    "status": run.status,
                    "error": run.info.get("error"),
                    "warnings": run.warnings,
                    "streams": summary,
                    "truncated": sorted(run.truncated),
                    "recorded_samples": run.info.get("samples"),
                    "samples_differ": differ,
                    "metadata": meta,
                },
                indent=2,
                default=str,
            )
        )
        return 0
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    console = Console()
    console.print(f"[bold]{escape(str(run.path))}[/bold]  status: {escape(run.status)}")
    if isinstance(run.info.get("error"), str):
        console.print(f"  [red]error: {escape(run.info['error'])}")
    for warning in run.warnings:
        console.print(f"  [yellow]warning: {escape(str(warning))}")
    for key in ("backend", "experiment", "duration_s", "seed"):
        if key in meta:
            value = experiment_name(meta) if key == "experiment" else meta[key]
            console.print(f"  {key}: {escape(str(value))}")
    if meta.get("object"):
        console.print(f"  object: {escape(_object_summary(meta['object']))}")
    if meta.get("stereo_truth"):
        try:
            truth = _surface_summary(meta["stereo_truth"])
        except (KeyError, TypeError, ValueError):
            raise ConfigError(f"{run.path / 'run.json'}: metadata.stereo_truth is incomplete") from None
        console.print(f"  reconstruction vs truth: {truth}")
    table = Table(title="streams")
    for col in ("stream", "samples", "rate (Hz)", "measured (Hz)", "duration (s)"):
        table.add_column(col, justify="right" if col != "stream" else "left")
    for st in summary:
        table.add_row(
            st["name"],
            str(st["samples"]),
            f"{st['rate_hz']:g}",
            f"{st['measured_rate_hz']:.2f}",
            f"{st['duration_s']:.2f}",
        )
    console.print(table)
    fields = Table(title="fields")
    for col in ("stream", "field", "unit", "kind", "shape"):
        fields.add_column(col)
    for st in summary:
        for name, f in st["fields"].items():
            fields.add_row(st["name"], name, escape(f["unit"]), f["kind"], escape(str(tuple(f["shape"]))))
    console.print(fields)
    if run.truncated:
        console.print(f"[yellow]truncated streams (crash recovery): {', '.join(sorted(run.truncated))}")
    never_closed = " (its last count: the run never closed)" if run.status == "running" else ""
    for d in differ:
        console.print(
            f"[yellow]{d['stream']}: {d['readable']} samples readable, run.json records "
            f"{d['recorded']}{never_closed}"
        )
    return 0


def _object_summary(obj: dict) -> str:
    """name (shape, E, nu) of a run's object, with whichever of them run.json records."""
    details = [obj["shape"]] if "shape" in obj else []
    if "young_pa" in obj:
        details.append(f"E = {obj['young_pa']:g} Pa")
    if "poisson" in obj:
        details.append(f"nu = {obj['poisson']:g}")
    return f"{obj.get('name', '?')} ({', '.join(details)})"


def cmd_compare(args: argparse.Namespace) -> int:
    """`twin compare A B`: same streams and units? finger positions after time alignment."""
    from twin.compare import contact_windows_s, describe, position_agreement, stream_mismatches

    mismatches = stream_mismatches(args.run_a, args.run_b)
    agreement = position_agreement(args.run_a, args.run_b)
    settled = position_agreement(args.run_a, args.run_b, exclude_s=contact_windows_s(args.run_a))
    if args.json:
        print(
            json.dumps(
                {
                    "mismatches": [vars(m) for m in mismatches],
                    "lag_s": agreement.lag_s,
                    "max_error_counts": agreement.max_error_counts.tolist(),
                    "rms_error_counts": agreement.rms_error_counts.tolist(),
                    "travel_counts": agreement.travel_counts.tolist(),
                    "max_relative_error": agreement.max_relative_error,
                    "max_relative_error_outside_contact": settled.max_relative_error,
                },
                indent=2,
            )
        )
        return 0
    if mismatches:
        for m in mismatches:
            print(f"differs: {m.stream}.{m.field}: {m.a} vs {m.b}")
    else:
        print("streams and units: the same (hand, command, tactile where both have it)")
    print("finger positions: " + describe(agreement))
    worst = settled.max_relative_error
    print(f"  outside the grasp (first contact to compression, +-0.25 s): worst {worst:.2%} of travel")
    return 0


def cmd_calibrate_cameras(args: argparse.Namespace) -> int:
    """`twin calibrate cameras`: stereo + camera-to-hand calibration on the twin (errors against its
    truth) or from image pairs on disk; writes the calibration file atomically."""
    if args.views is not None and args.seed is not None:
        raise ConfigError("--seed is for the sim; --views calibrates from the images given")
    if args.out.is_dir():
        raise ConfigError(f"--out {args.out}: is a directory")
    if not args.out.parent.is_dir():
        raise ConfigError(f"--out {args.out}: no such directory {args.out.parent}")
    if args.out.exists() and not args.force:
        raise ConfigError(f"--out {args.out}: exists; choose another file or overwrite it with --force")
    from experiments.calibrate_cameras import calibrate_sim, calibrate_views

    outcome = calibrate_views(args.views) if args.views is not None else calibrate_sim(seed=args.seed or 0)
    for line in outcome.summary():
        print(line)
    print(f"wrote {outcome.calibration.save(args.out)}")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    """`twin view DIR`: the Rerun viewer, or how to get one when there is no display."""
    from twin.session import RRD_NAME

    rrd = args.run_dir / RRD_NAME
    if not rrd.is_file():
        return _fail(f"no Rerun recording at {rrd}")
    # analyses of the run (`twin identify`) log under the same recording id: the viewer merges them
    files = [str(rrd), *sorted(str(p) for p in args.run_dir.glob("*/*.rrd"))]
    has_display = (
        sys.platform in ("darwin", "win32") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )
    if not has_display:
        print(f"No display here. Copy {' '.join(files)} to a machine with one and run `rerun FILES`,")
        print(f"or serve them to a browser from here: `rerun --serve-web {' '.join(files)}`.")
        return 0
    viewer = shutil.which("rerun")
    cmd = [viewer, *files] if viewer else [sys.executable, "-m", "rerun", *files]
    return subprocess.call(cmd)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `twin` console script."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0), or an argument refused in one line (2): a status, as below
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    handlers = {
        "objects": cmd_objects,
        "info": cmd_info,
        "view": cmd_view,
        "emulate": cmd_emulate,
        "compare": cmd_compare,
        "identify": cmd_identify,
        "fit": cmd_fit,
        "sweep": cmd_sweep,
        "train": cmd_train,
    }
    from twin.processes import sigterm_as_interrupt

    previous = signal.getsignal(signal.SIGTERM)
    sigterm_as_interrupt()  # `kill PID`, a batch system or `timeout` ends a command as Ctrl-C does
    try:
        if args.command == "run":
            return cmd_run_free(args) if args.experiment == "free" else cmd_run_compress(args)
        if args.command == "calibrate":
            return cmd_calibrate_cameras(args)
        return handlers[args.command](args)
    except TwinError as exc:
        return _fail(str(exc))
    except (FileExistsError, PermissionError) as exc:
        return _fail(f"{exc.filename}: {exc.strerror}" if exc.filename and exc.strerror else str(exc))
    except ValueError as exc:  # RunFormatError: not a readable run directory
        from twin.recording import RunFormatError

        if isinstance(exc, RunFormatError):
            return _fail(str(exc))
        raise
    except KeyboardInterrupt:
        print(f"twin: interrupted; {_INTERRUPTED.get(args.command, 'nothing was written')}", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        with contextlib.suppress(ValueError, TypeError):  # not the main thread / a foreign handler
            signal.signal(signal.SIGTERM, previous)


_INTERRUPTED = {
    "run": "the run directory is marked 'interrupted' and keeps what was recorded",
    "sweep": "the finished trajectories are kept (run the same command again to resume)",
    "emulate": "the emulator stopped",
}
"""What an interruption (Ctrl-C or SIGTERM) leaves, per command; the others write only at the end."""


if __name__ == "__main__":
    sys.exit(main())
