"""`twin objects`: the foam library as a table or JSON."""

from __future__ import annotations

import argparse
import json


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser("objects", help="list the foam library")
    p.add_argument("--json", action="store_true", help="print a JSON list of objects")


def cmd_objects(args: argparse.Namespace) -> int:
    """`twin objects`: the foam library."""
    from twin.sim.foam import LIBRARY

    if args.json:
        print(json.dumps([p.to_json() for p in LIBRARY.values()], indent=2))
        return 0
    from rich import box
    from rich.console import Console
    from rich.table import Table

    # Compact columns, none wrapped: the table fits 80 columns whole (names and sizes were cut there)
    table = Table(title="Foam library (--json: every parameter)", box=box.SIMPLE_HEAD, padding=(0, 1, 0, 0))
    for col in ("name", "shape", "size mm", "E kPa", "nu", "class", "kg/m^3", "mass g", "fidelity"):
        table.add_column(col, no_wrap=True, justify="left" if col in ("name", "shape", "class") else "right")
    for p in LIBRARY.values():
        table.add_row(
            p.name,
            p.shape,
            "x".join(f"{s * 1e3:.0f}" for s in p.size_m),
            f"{p.young_pa / 1e3:g}",
            f"{p.poisson:g}",
            p.stiffness_class,
            f"{p.density_kg_m3:g}",
            f"{p.mass_kg * 1e3:.1f}",
            p.fidelity,
        )
    Console().print(table)
    return 0


command = cmd_objects
