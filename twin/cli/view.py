"""`twin view`: a run in the Rerun viewer."""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import subprocess
import sys

from twin.cli.common import fail
from twin.validation import existing_dir


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser("view", help="open a run in the Rerun viewer")
    p.add_argument("run_dir", type=existing_dir(), metavar="DIR")


def cmd_view(args: argparse.Namespace) -> int:
    """`twin view DIR`: the Rerun viewer, or how to get one when there is no display."""
    from twin.session import RRD_NAME

    rrd = args.run_dir / RRD_NAME
    if not rrd.is_file():
        return fail(f"no Rerun recording at {rrd}")
    # analyses of the run (`twin identify`) log under the same recording id: the viewer merges them
    files = [str(rrd), *sorted(str(p) for p in args.run_dir.glob("*/*.rrd"))]
    has_display = (
        sys.platform in ("darwin", "win32") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )
    if not has_display:
        quoted = " ".join(shlex.quote(f) for f in files)
        print("No display here. Either copy the run directory to a machine with one and open it there:")
        print(f"  twin view {shlex.quote(args.run_dir.name)}")
        print("or serve the recording to a browser from here (then open the address it prints):")
        print(f"  {shlex.quote(sys.executable)} -m rerun --serve-web {quoted}")
        return 0
    viewer = shutil.which("rerun")
    cmd = [viewer, *files] if viewer else [sys.executable, "-m", "rerun", *files]
    return subprocess.call(cmd)


command = cmd_view
