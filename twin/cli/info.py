"""`twin info`: a run directory's streams, rates, fields and metadata."""

from __future__ import annotations

import argparse
import json

from twin.cli.common import surface_summary
from twin.interface.errors import ConfigError
from twin.recording.liveness import writer_alive
from twin.validation import check_run_metadata, experiment_name, run_dir


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser("info", help="summarize a run directory")
    p.add_argument("run_dir", type=run_dir(), metavar="DIR", help="a run directory (one holding a run.json)")
    p.add_argument(
        "--json",
        action="store_true",
        help="print the summary as JSON: status, streams with their rates and units, metadata",
    )


def cmd_info(args: argparse.Namespace) -> int:
    """`twin info DIR`: streams, sample counts, rates, duration, metadata."""
    from twin.recording import open_run

    run = open_run(args.run_dir)
    meta = check_run_metadata(run.info, run.path / "run.json")
    alive = writer_alive(run.info) if run.status == "running" else None
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
                    "writer_alive": alive,
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
    console.print(f"[bold]{escape(str(run.path))}[/bold]  status: {escape(_status(run.status, alive))}")
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
    if isinstance(meta.get("foam_calibration"), dict):
        console.print(f"  foam calibration: {escape(_calibration_summary(meta['foam_calibration']))}")
    for line in _envelope_lines(meta):
        console.print(f"  {escape(line)}")
    if meta.get("stereo_truth"):
        try:
            truth = surface_summary(meta["stereo_truth"])
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


def _envelope_lines(meta: dict) -> list[str]:
    """The squeeze the compress procedure chose (inside the fingertip-force cap) and how often a finger
    still reached the cap, as run.json records them; nothing for what a run did not record (or a file
    whose fields are not numbers: a hostile run.json prints less, never a traceback)."""
    lines = []
    squeeze, cap = meta.get("squeeze_amplitude"), meta.get("force_cap")
    if isinstance(squeeze, dict) and isinstance(squeeze.get("amplitude_counts"), int | float):
        line = f"squeeze: {squeeze['amplitude_counts']:.0f} counts"
        if isinstance(squeeze.get("scale"), int | float):
            line += f" (x {squeeze['scale']:.2f} of the profile's wave)"
        if isinstance(squeeze.get("why"), str):
            line += f"; {squeeze['why']}"
        lines.append(line)
    if isinstance(cap, dict) and isinstance(cap.get("readings_at_cap"), list):
        counts, names = cap["readings_at_cap"], cap.get("fingers") or ["F1", "F2", "F3"]
        if all(isinstance(c, int) for c in counts) and len(counts) == len(names):
            limit = cap.get("limit_kg")
            at = f"{limit:g} kg " if isinstance(limit, int | float) else ""
            lines.append(f"readings at the {at}fingertip-force cap: " + ", ".join(
                f"{n} {c}" for n, c in zip(names, counts, strict=True)))  # fmt: skip
    loop = meta.get("hand_loop")
    if isinstance(loop, dict) and isinstance(loop.get("times_behind"), int) and loop["times_behind"] > 0:
        longest, period = loop.get("longest_behind_ms"), loop.get("period_ms")
        if isinstance(longest, int | float) and isinstance(period, int | float):
            lines.append(f"hand loop: over one period ({period:.1f} ms) behind its schedule "
                         f"{loop['times_behind']} time(s), at most {longest:.0f} ms")  # fmt: skip
    return lines


def _calibration_summary(cal: dict) -> str:
    """k on the flex's modulus and its source (twin.sim.calibration), as run.json records them."""
    k = cal.get("modulus_scale")
    text = f"flex modulus = E x {k:.3g}" if isinstance(k, int | float) else "flex modulus scale unknown"
    source = {
        "calibrated": "fitted to an FEM of the fingertip contact",
        "law": "the shape's law through FEM calibrations",
    }
    text += f" ({source.get(cal.get('source'), cal.get('why', 'uncalibrated'))}"
    if cal.get("date"):
        text += f", {cal['date']}"
    return text + ")"


def _status(status: str, writer_alive: bool | None) -> str:
    """The status as run.json has it, and for a `running` run whether its writer still lives."""
    if status != "running" or writer_alive is None:
        return status
    if writer_alive:
        return "running (being written now)"
    return "running, but its writer is gone: killed or crashed, it will never close (treat as incomplete)"


def _object_summary(obj: dict) -> str:
    """name (shape, E, nu) of a run's object, with whichever of them run.json records."""
    details = [obj["shape"]] if "shape" in obj else []
    if "young_pa" in obj:
        details.append(f"E = {obj['young_pa']:g} Pa")
    if "poisson" in obj:
        details.append(f"nu = {obj['poisson']!r}")  # as recorded: 0.49999999999 is not 0.5
    return f"{obj.get('name', '?')} ({', '.join(details)})"


command = cmd_info
