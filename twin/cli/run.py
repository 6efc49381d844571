"""`twin run compress|free`: an experiment on the twin or the rig, through the API (twin.api)."""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from twin.cli.common import (
    add_foam_overrides,
    add_object_mesh,
    add_run_options,
    print_completion,
    surface_summary,
    with_progress,
)
from twin.interface.errors import ConfigError, RunWarning
from twin.validation import existing_dir, existing_file

if TYPE_CHECKING:
    from twin.interface.backend import Backend
    from twin.session import RunOutcome
    from twin.sim.foam import FoamParams


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser("run", help="run an experiment")
    run_sub = p.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    c = run_sub.add_parser("compress", help="grasp, balance, then periodic compression (paper §6.2)")
    c.add_argument(
        "--object",
        help="library object, see `twin objects` (default: block); on hardware the object in the hand, as "
        "the run records it for `twin fit` (default there: none named)",
    )
    add_object_mesh(c, "in the twin's hand")
    add_run_options(c, duration_s=10.0)
    c.add_argument(
        "--cameras", action="store_true", help="sample the stereo pair at 30 fps and reconstruct the foam"
    )
    c.add_argument(
        "--camera-placement",
        metavar="NAMES",
        help="sim cameras: where the stereo pairs stand, one pair each, comma-separated (lateral, opposite, "
        "top; default lateral): every pair is recorded (`stereo`, then `stereo_<name>`); lateral,opposite "
        "sees both x faces and reads the Poisson ratio (docs/identification.md)",
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
    add_foam_overrides(c)

    f = run_sub.add_parser("free", help="swing the empty hand's fingers (identifies eq. 4's hand terms)")
    add_run_options(f, duration_s=20.0)


_FOAM_FLAGS = [
    ("--object-mesh", "object_mesh"),
    ("--young", "young"),
    ("--poisson", "poisson"),
    ("--damping", "damping"),
    ("--density", "density"),
    ("--size-mm", "size_mm"),
    ("--placement-mm", "placement_mm"),
    ("--fidelity", "fidelity"),
    ("--resolution", "resolution"),
    ("--dof", "dof"),
    ("--friction", "friction"),
]
"""The options that shape the twin's foam (add_foam_overrides, --object-mesh): (flag, dest)."""


def _foam_from_args(args: argparse.Namespace) -> FoamParams:
    """The object of `twin run compress`: --object with its overrides (mm on the command line, m in the
    API), or --object-mesh with --object's material."""
    from twin import api

    return api.foam(
        args.object or "block",
        mesh=getattr(args, "object_mesh", None),
        mesh_scale_m=getattr(args, "mesh_scale", 0.001),
        young_pa=args.young,
        poisson=args.poisson,
        damping=args.damping,
        density_kg_m3=args.density,
        size_m=tuple(s / 1e3 for s in args.size_mm) if args.size_mm else None,
        fidelity=args.fidelity,
        resolution=args.resolution,
        dof=args.dof,
        friction=args.friction,
        placement_m=tuple(v / 1e3 for v in args.placement_mm) if args.placement_mm else None,
    )


def _backend(args: argparse.Namespace, foam: FoamParams | None, cameras: bool = False) -> Backend:
    """--backend sim: the twin holding `foam`; --backend hardware: the rig of --rig / --hand."""
    from twin import api

    if args.backend == "sim":
        if args.hand or args.rig:
            raise ConfigError("--hand and --rig need --backend hardware")
        return api.sim_backend(
            foam,
            seed=args.seed,
            cameras=cameras,
            render_native=getattr(args, "render_native", False),
            stereo_calibration=getattr(args, "stereo_calibration", None),
            camera_placements=getattr(args, "camera_placement", None),
        )
    if getattr(args, "camera_placement", None) is not None:
        raise ConfigError("--camera-placement is for the sim; on hardware the rig's cameras are in rig.toml")
    if getattr(args, "stereo_calibration", None) is not None:
        raise ConfigError("--stereo-calibration is for the sim; on hardware set calibration in [stereo]")
    return api.hardware_backend(args.rig, hand=args.hand, cameras=cameras)


def cmd_compress(args: argparse.Namespace) -> int:
    """`twin run compress`: validate, run, report."""
    from twin import api

    foam = _foam_from_args(args)
    # On hardware the run records the object the researcher named (twin fit reads it), never a default,
    # and nothing the hand cannot hold: the overrides shape only the twin's foam.
    object_name = foam.name if args.backend == "sim" or args.object is not None else None
    if args.backend == "hardware":
        given = [flag for flag, dest in _FOAM_FLAGS if getattr(args, dest, None) is not None]
        if given:
            raise ConfigError(
                f"{', '.join(given)}: the twin's foam only; a hardware run records the object's name "
                "(--object) and `twin fit`/`twin identify` take its size"
            )
    shape_model = None if args.predict is None else api.load_shape_model(args.predict, object_name)
    if (args.bbox is not None or args.stereo_calibration is not None) and not args.cameras:
        raise ConfigError("--bbox and --stereo-calibration need --cameras")
    if args.camera_placement is not None and not args.cameras:
        raise ConfigError("--camera-placement needs --cameras")
    box = None
    if args.bbox is not None:
        from twin.vision.pipeline import parse_box

        box = parse_box(args.bbox)
    backend = _backend(args, foam, cameras=args.cameras)
    outcome = _run_with_progress(
        args,
        lambda progress: api.compress(
            backend,
            duration_s=args.duration,
            out=args.out,
            object_name=object_name,
            progress=progress,
            stereo_box=box,
            shape_model=shape_model,
            argv=sys.argv,
        ),
    )
    truth = print_completion(outcome).get("stereo_truth")
    if truth:
        print(f"reconstruction vs the twin's truth: {surface_summary(truth)}")
    print(f"view it: twin view {outcome.run_dir}")
    return 0


def _run_with_progress(args: argparse.Namespace, run: Callable[[Any], RunOutcome]) -> RunOutcome:
    """`run(progress)` under the command's progress bar; the API's RunWarnings silenced, since
    print_completion says each as its own line."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RunWarning)
        return with_progress(args.duration, not args.no_progress, run)


def cmd_free(args: argparse.Namespace) -> int:
    """`twin run free`: the empty hand swings its fingers (eq. 4's hand terms)."""
    from twin import api

    backend = _backend(args, None)
    outcome = _run_with_progress(
        args,
        lambda progress: api.free(
            backend, duration_s=args.duration, out=args.out, progress=progress, argv=sys.argv
        ),
    )
    print_completion(outcome)
    print(f"use it: twin identify RUN --free {outcome.run_dir}")
    return 0


def command(args: argparse.Namespace) -> int:
    """`twin run EXPERIMENT`."""
    return cmd_free(args) if args.experiment == "free" else cmd_compress(args)
