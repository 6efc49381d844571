"""`twin emulate hand|rig`: serve the twin-backed emulators until Ctrl-C or --duration."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from twin.cli.common import add_foam_overrides, add_object_mesh
from twin.interface.errors import ConfigError
from twin.outputs import check_writable
from twin.validation import duration, finite, integer, out_file, seed

if TYPE_CHECKING:
    from twin.sim.foam import FoamParams


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
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
    add_object_mesh(p, "in the emulated hand")
    p.add_argument("--seed", type=seed(), default=0, help="seed of the twin's sensor noise")
    p.add_argument(
        "--rig-file",
        type=out_file(make_parents=True),
        metavar="FILE",
        help="write a rig.toml pointing here, and its calibration files beside it, creating the directory "
        "(rig: always; default: a temporary directory)",
    )
    p.add_argument(
        "--duration", type=duration(), metavar="S", help="stop after S seconds, up to a day (default: Ctrl-C)"
    )
    p.add_argument(
        "--no-cameras", action="store_true", help="rig: leave the stereo cameras out (they cost CPU)"
    )
    p.add_argument(
        "--camera-placement",
        metavar="NAMES",
        help="rig: where the stereo pairs stand, one pair each, comma-separated (lateral, opposite, top; "
        "default lateral); lateral,opposite gives `twin identify --poisson-from-cameras` its two pairs "
        "(each pair renders in a process of its own: ~a core at 30 fps)",
    )
    p.add_argument(
        "--camera-rate",
        type=finite(0, 120, min_inclusive=False),
        metavar="HZ",
        help="rig: the emulated cameras' frame rate, written to rig.toml (default: the Flea2's 30 fps; "
        "two pairs on 2 cores keep up at ~10)",
    )
    add_foam_overrides(p)  # the object a lab's hand would hold: a modulus, size or placement to identify


def cmd_emulate(args: argparse.Namespace) -> int:
    """`twin emulate hand|rig`: serve the twin-backed emulators until Ctrl-C (or --duration)."""
    import time

    from twin.hardware.bh262.driver import SUPPORTED_BAUD

    if args.baud not in SUPPORTED_BAUD:
        raise ConfigError(f"--baud {args.baud}: not one of {', '.join(map(str, SUPPORTED_BAUD))}")
    where = args.port
    if where != "pty" and not (
        where.startswith("tcp:") and where[4:].isascii() and where[4:].isdigit() and int(where[4:]) < 65536
    ):
        raise ConfigError(f"--port {where!r}: expected pty or tcp:PORT (tcp:0 picks a free port)")
    for flag, value in (("--camera-placement", args.camera_placement), ("--camera-rate", args.camera_rate)):
        if value is not None and (args.what != "rig" or args.no_cameras):
            raise ConfigError(f"{flag} is for `twin emulate rig` with its cameras")
    pairs = 1 if args.camera_placement is None else len(args.camera_placement.split(","))
    pairs = 0 if args.what != "rig" or args.no_cameras else pairs
    last = 65535 - 1 - pairs  # the hand on PORT, the pads on PORT+1, pair k's cameras on PORT+2+k
    if args.what == "rig" and where != "pty" and int(where[4:]) > last:
        raise ConfigError(f"--port {where}: the rig serves PORT to PORT+{1 + pairs}: at most tcp:{last}")
    if args.rig_file is not None:
        check_writable(args.rig_file.parent, "--rig-file")  # before the twin starts
    from twin.hardware.bh262.emulator import make_hand_emulator
    from twin.hardware.rig_config import rig_toml
    from twin.hardware.rig_emulator import RigEmulator

    foam = _foam_from_args(args)  # unknown names, bad meshes and sizes fail here, in one line

    def event(message: str) -> None:
        print(f"[emulator] {message}", flush=True)

    if args.what == "hand":
        emulator = make_hand_emulator(
            foam, baud=args.baud, faults=args.faults, seed=args.seed, on_event=event
        )
    else:
        emulator = RigEmulator(
            foam,
            baud=args.baud,
            faults=args.faults,
            tactile_faults=args.tactile_faults,
            seed=args.seed,
            on_event=event,
            cameras=not args.no_cameras,
            camera_placements=args.camera_placement,
            camera_rate_hz=args.camera_rate,
        )
    try:
        if args.what == "hand":
            address = emulator.serve_pty() if where == "pty" else emulator.serve_tcp(int(where[4:]))
        else:
            address, tactile_address = emulator.serve(where)
    except OSError as exc:
        emulator.close()
        raise ConfigError(f"--port {where}: {exc.strerror or exc}") from None
    print(f"hand: {address}  (BH8-262 at {args.baud} baud, object: {_described(foam)})", flush=True)
    if args.what == "rig":
        print(f"tactile: {tactile_address}  (PPS pads, 162 taxels at 30 Hz)", flush=True)
        if emulator.camera_addresses is None:
            print("cameras: not emulated (--no-cameras)", flush=True)
        for camera, (left, right) in zip(emulator.camera_pairs, emulator.camera_pair_addresses, strict=True):
            where_from = f", {camera.name}" if len(emulator.camera_pairs) > 1 else ""
            print(
                f"cameras: {left}  {right}  (MJPEG over HTTP, 320x240 at {camera.rate_hz:g} fps{where_from})",
                flush=True,
            )
        print(f"rig file: {emulator.write_rig_file(args.rig_file)}", flush=True)
    elif args.rig_file:
        args.rig_file.parent.mkdir(parents=True, exist_ok=True)
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


def _foam_from_args(args: argparse.Namespace) -> FoamParams | None:
    """The foam in the emulated hand: --object with --object-mesh and the overrides, as `twin run
    compress` builds it; None for `--object none` (which takes none of them)."""
    from twin.cli.run import _FOAM_FLAGS
    from twin.cli.run import _foam_from_args as run_foam

    if args.object == "none":
        given = [flag for flag, dest in _FOAM_FLAGS if getattr(args, dest, None) is not None]
        if given:
            raise ConfigError(f"{', '.join(given)}: --object none leaves the hand empty")
        return None
    return run_foam(args)


def _described(foam: FoamParams | None) -> str:
    """The object in one phrase for the ready lines: its name, extents and material."""
    import numpy as np

    if foam is None:
        return "none"
    size = " x ".join(f"{1e3 * s:.4g}" for s in foam.size_m)
    placed = (
        ""
        if not any(foam.placement_m)
        else " at ({:+.3g}, {:+.3g}) mm".format(*1e3 * np.array(foam.placement_m))
    )
    return f"{foam.name}, {size} mm{placed}, E {foam.young_pa / 1e3:.4g} kPa, Poisson {foam.poisson:.3g}"


command = cmd_emulate
