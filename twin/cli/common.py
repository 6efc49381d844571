"""What every `twin` command shares: the one-line error form, option types and groups, progress and
the lines a finished run prints."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from twin.interface.errors import ConfigError
from twin.validation import check_run_metadata, duration, existing_file, finite, integer, new_dir, seed

T = TypeVar("T")

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
"""128 + SIGINT, as a shell reports a Ctrl-C; SIGTERM is treated the same."""


def fail(message: str) -> int:
    """Print the one line `twin: error: MESSAGE` on stderr; the usage exit status."""
    print(f"twin: error: {message}", file=sys.stderr)
    return EXIT_USAGE


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """--help lines end with the option's default where it has one worth showing (not None or False),
    unless the help already names it; a list default reads as it is typed (`a b`, not `['a', 'b']`)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (
            default is None
            or default is False
            or default == argparse.SUPPRESS
            or "default" in text
            or not action.option_strings
            or action.nargs == 0
        ):
            return action.help
        shown = (
            " ".join(str(v) for v in default).replace("%", "%%")
            if isinstance(default, list | tuple)
            else "%(default)s"
        )
        return f"{text} (default: {shown})" if text else f"(default: {shown})"


class TwinArgumentParser(argparse.ArgumentParser):
    """argparse with the house's error form: one line `twin: error: ...` on stderr and exit status 2
    (argparse's own prints the usage first: two lines or more)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)

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


def add_foam_overrides(p: argparse.ArgumentParser) -> None:
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


def add_object_mesh(p: argparse.ArgumentParser, where: str) -> None:
    """--object-mesh (a closed surface file becomes the foam, with --object's material) and its
    --mesh-scale; `where`: whose foam it is, for the help line."""
    p.add_argument(
        "--object-mesh",
        type=existing_file(),
        metavar="FILE",
        help=f"a foam of any closed shape {where}: an .stl/.obj surface (e.g. a scan), with --object's "
        "material",
    )
    add_mesh_scale(p)


def add_mesh_scale(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--mesh-scale",
        type=finite(1e-6, 1, min_inclusive=True),
        default=0.001,
        metavar="M",
        help="metres per --object-mesh unit (default 0.001: the file is in millimetres)",
    )


def add_run_options(p: argparse.ArgumentParser, duration_s: float) -> None:
    """What every `twin run` experiment takes: backend, hand, rig, duration, seed, output, progress."""
    p.add_argument(
        "--backend", choices=("sim", "hardware"), default="sim", help="the twin, or the rig's devices"
    )
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


def run_metadata(path: Path, flag: str) -> dict:
    """run.json's metadata, with the types the analyses read; one line naming the file and key if not."""
    run_json = path / "run.json"
    try:
        info = json.loads(run_json.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"{flag} {path}: run.json is unreadable ({exc})") from None
    except RecursionError:
        raise ConfigError(f"{flag} {path}: run.json is unreadable (nested too deeply)") from None
    return check_run_metadata(info, run_json)


def print_completion(outcome) -> dict:  # noqa: ANN001 - twin.session.RunOutcome, imported lazily
    """'run complete' on stdout; on stderr each of the run's warnings (a loop that missed its rate) and
    how many hand cycles the driver recovered (each is listed in run.json). Returns run.json's metadata."""
    from twin.session import completion_warnings

    print(f"run complete: {outcome.run_dir}  ({outcome.result.samples.get('hand', 0)} hand samples)")
    for warning in completion_warnings(outcome):
        print(f"twin: warning: {warning}", file=sys.stderr)
    return json.loads((outcome.run_dir / "run.json").read_text())["metadata"]


def surface_summary(truth: dict) -> str:
    """One line: a run's reconstruction accuracy against the twin's truth."""
    return (
        f"median {truth['median_mm']:.2f} mm (worst frame {truth['worst_median_mm']:.2f}), "
        f"coverage {100 * truth['coverage']:.0f} % (worst {100 * truth['worst_coverage']:.0f} %), "
        f"{100 * truth['frames_within_targets']:.0f} % of {truth['frames']} frames within "
        f"{truth['targets']['median_mm']:g} mm / {100 * truth['targets']['coverage']:.0f} %"
    )


def with_progress(duration_s: float, show: bool, job: Callable[[Callable[[float], None] | None], T]) -> T:
    """job(progress) under a run-time bar that is drawn from the run's first reading on, so a refusal
    before the run starts (a bad file, a hand that is not there) leaves the terminal its one line."""
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
    bar = Progress(*columns, transient=False)
    task = None

    def progress(t_s: float) -> None:
        nonlocal task
        if task is None:
            bar.start()
            task = bar.add_task("run time", total=duration_s)
        bar.update(task, completed=min(t_s, duration_s))

    try:
        return job(progress)
    finally:
        if task is not None:
            bar.stop()
