"""`twin calibrate cameras`: stereo and camera-to-hand calibration."""

from __future__ import annotations

import argparse
from pathlib import Path

from twin.interface.errors import ConfigError
from twin.outputs import check_writable
from twin.validation import existing_dir, out_file, seed


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
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
    check_writable(args.out.parent)  # before the calibration is computed
    from twin.experiments.calibrate_cameras import calibrate_sim, calibrate_views

    outcome = calibrate_views(args.views) if args.views is not None else calibrate_sim(seed=args.seed or 0)
    for line in outcome.summary():
        print(line)
    print(f"wrote {outcome.calibration.save(args.out)}")
    return 0


command = cmd_calibrate_cameras
