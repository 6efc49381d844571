"""The `twin` command line: argument parsing and printing over the Python API (twin.api) and the
analyses, one module per command: objects, run, identify, fit, sweep, train, emulate, info, compare,
view, calibrate, export.

Bad input ends with one line on stderr and exit status 2; nothing is simulated or written first.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys

from twin.cli import (
    calibrate,
    compare,
    emulate,
    export,
    fit,
    identify,
    info,
    objects,
    run,
    sweep,
    train,
    view,
)
from twin.cli.common import EXIT_INTERRUPTED, EXIT_USAGE, TwinArgumentParser, fail
from twin.cli.run import _foam_from_args  # noqa: F401  (tests build foams as `twin run` does)
from twin.interface.errors import TwinError

COMMANDS = {
    "objects": objects,
    "run": run,
    "identify": identify,
    "fit": fit,
    "sweep": sweep,
    "train": train,
    "emulate": emulate,
    "info": info,
    "compare": compare,
    "view": view,
    "calibrate": calibrate,
    "export": export,
}
"""Each command's module: `add_parser(sub)` declares it, `command(args)` runs it (in --help's order)."""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `twin`."""
    from twin import __version__

    parser = TwinArgumentParser(
        prog="twin",
        description="Barrett BH8 digital twin: simulate, record and view foam compression runs; identify the "
        "foam (eq. 4), fit the twin to a run, train the shape network, and export runs for learning.",
    )
    parser.add_argument("--version", action="version", version=f"twin {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS.values():
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `twin` console script."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0), or an argument refused in one line (2): a status, as below
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    from twin.processes import sigterm_as_interrupt

    previous = signal.getsignal(signal.SIGTERM)
    sigterm_as_interrupt()  # `kill PID`, a batch system or `timeout` ends a command as Ctrl-C does
    try:
        status = COMMANDS[args.command].command(args)
        sys.stdout.flush()  # a reader that left (`| head`) is noticed here, where it is handled
        return status
    except TwinError as exc:
        return fail(str(exc))
    except (FileExistsError, PermissionError) as exc:
        return fail(f"{exc.filename}: {exc.strerror}" if exc.filename and exc.strerror else str(exc))
    except ValueError as exc:  # RunFormatError: not a readable run directory
        from twin.recording import RunFormatError

        if isinstance(exc, RunFormatError):
            return fail(str(exc))
        raise
    except ModuleNotFoundError as exc:  # an extra this install left out
        extra = _EXTRAS.get((exc.name or "").split(".")[0])
        if extra is None:
            raise
        return fail(f"`twin {args.command}` needs {exc.name}: pip install 'barrett-twin[{extra}]'")
    except BrokenPipeError:  # `twin objects --json | head`: the reader left; say nothing more
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print(f"twin: interrupted; {_INTERRUPTED.get(args.command, 'nothing was written')}", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        with contextlib.suppress(ValueError, TypeError):  # not the main thread / a foreign handler
            signal.signal(signal.SIGTERM, previous)


_EXTRAS = {
    "dm_control": "sim",
    "gmsh": "sim",
    "meshio": "sim",
    "torch": "shape",
    "gymnasium": "gym",
    "ray": "cluster",
}
"""The install extra that brings each optional import (pyproject.toml)."""

_INTERRUPTED = {
    "run": "the run directory is marked 'interrupted' and keeps what was recorded",
    "sweep": "the finished trajectories are kept (run the same command again to resume)",
    "emulate": "the emulator stopped",
    "export": "the output directory may be incomplete",
}
"""What an interruption (Ctrl-C or SIGTERM) leaves, per command; the others write only at the end."""


if __name__ == "__main__":
    sys.exit(main())
