"""The `twin` command line: argument parsing and printing over the Python API (twin.api) and the
analyses, one module per command: objects, run, identify, fit, sweep, train, emulate, info, compare,
view, calibrate, export.

Bad input ends with one line on stderr and exit status 2; nothing is simulated or written first.
"""

from __future__ import annotations

import argparse
import contextlib
import json
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
    from twin import rendering

    # twin renders only through twin.rendering, on EGL (or MUJOCO_GL's choice): MuJoCo's default
    # context stays off, so a run without cameras loads no OpenGL.
    rendering.disable_default_context()
    # Rerun's own log lines (e.g. its file sink on a full disk) would follow the one error line: the
    # CLI says what failed itself. RUST_LOG set by the user still wins.
    os.environ.setdefault("RUST_LOG", "off")
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0), or an argument refused in one line (2): a status, as below
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    if sys.stdout is None:  # started with its standard output closed (`>&-`): say so, and do nothing
        return fail("<stdout>: closed (the command's output has nowhere to go)")
    from twin.processes import sigterm_as_interrupt

    previous = signal.getsignal(signal.SIGTERM)
    sigterm_as_interrupt()  # `kill PID`, a batch system or `timeout` ends a command as Ctrl-C does
    stdout, sys.stdout = sys.stdout, _Output(sys.stdout)
    exiting = False
    try:
        status = COMMANDS[args.command].command(args)
        sys.stdout.flush()  # a reader that left (`| head`) is noticed here, where it is handled
        return status
    except TwinError as exc:
        return fail(str(exc))
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
        _drop_stdout()
        return 0
    except OSError as exc:  # any file-system or device fault: one line naming the path and the reason
        if exc.filename == STDOUT:
            _drop_stdout()
        return fail(os_error_line(exc))
    except RecursionError:  # a hostile file nested 100,000 deep that no reader above caught
        return fail("an input file is nested too deeply to read")
    except RuntimeError as exc:  # MuJoCo's own refusal of its environment, at its first render
        if "MUJOCO_GL" not in str(exc):
            raise
        return fail(f"{exc}; set MUJOCO_GL to egl, osmesa or glx (or leave it unset)")
    except KeyboardInterrupt as exc:
        # What was written is final now: a further Ctrl-C (or SIGTERM) is ignored until exit, so the
        # line below is printed and the exit status is 130, never a death by the signal itself.
        # (Only the console script: a caller of main(argv) keeps its own handlers.)
        exiting = argv is None
        if exiting:
            _ignore_interrupts()
        print(f"twin: interrupted; {_interrupted(args.command, exc)}", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        sys.stdout = stdout
        if not exiting:
            with contextlib.suppress(ValueError, TypeError):  # not the main thread / a foreign handler
                signal.signal(signal.SIGTERM, previous)


def _ignore_interrupts() -> None:
    """SIGINT and SIGTERM ignored from now on (the console script, about to exit)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(ValueError, OSError):
            signal.signal(sig, signal.SIG_IGN)


def _interrupted(command: str, exc: KeyboardInterrupt) -> str:
    """What an interruption left, for a run read back from its run.json (what was written, not what
    was meant to be), else the command's usual words."""
    run_dir = getattr(exc, "run_dir", None)
    if run_dir is None:
        return _INTERRUPTED.get(command, "nothing was written") if command != "run" else "nothing was written"
    try:
        with open(os.path.join(run_dir, "run.json"), encoding="utf-8") as f:
            status = json.load(f).get("status")
    except (OSError, ValueError, AttributeError, RecursionError) as read:
        return f"{run_dir}: its status could not be read back ({read})"
    if status == "interrupted":
        return f"the run directory {run_dir} is marked 'interrupted' and keeps what was recorded"
    if status == "running":
        return f"the run directory {run_dir} still says 'running': its final status could not be written"
    return f"the run directory {run_dir} is marked {status!r}"


def os_error_line(exc: OSError) -> str:
    """`PATH: reason` for an OSError (`<stdout>: reason` for a failed write to the output)."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    if exc.filename is not None:
        path = os.fsdecode(exc.filename) if isinstance(exc.filename, bytes) else str(exc.filename)
        if exc.filename2 is not None:
            path += f" -> {exc.filename2}"
        return f"{path.encode('utf-8', 'backslashreplace').decode()}: {reason}"
    return reason


STDOUT = "<stdout>"
"""The file name an error writing the command's output carries (_Output)."""


class _Output:
    """sys.stdout for the length of a command: an error writing it (/dev/full, a reader gone) names
    <stdout>, so the one error line says it was the output that failed, not a file."""

    def __init__(self, stream: object) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), STDOUT) from None

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), STDOUT) from None

    def __getattr__(self, name: str) -> object:
        return getattr(self._stream, name)


def _drop_stdout() -> None:
    """Point stdout at /dev/null: what is still buffered for a reader that left or a full device is
    dropped, not flushed again (and failed again) at exit."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


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
