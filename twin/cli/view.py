"""`twin view`: a run in the Rerun viewer, with the blueprint of its kind of run."""

from __future__ import annotations

import argparse
import getpass
import os
import shlex
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from twin.cli.common import fail
from twin.validation import existing_dir, integer

WEB_VIEWER_PORT = 9090
"""Rerun's web viewer (HTTP) port, its default."""
GRPC_PORT = 9876
"""Rerun's gRPC server port (the recordings), its default."""
APPLICATION_ID = "barrett_twin"
PORT = integer(1, 65535)
"""A TCP port."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser("view", help="open a run in the Rerun viewer")
    p.add_argument("run_dir", type=existing_dir(), metavar="DIR", help="a run directory (holding run.rrd)")
    p.add_argument(
        "--port",
        type=PORT,
        default=GRPC_PORT,
        help="Rerun's gRPC port: the native viewer's server, or (headless) the server of the recording",
    )
    p.add_argument(
        "--web-viewer-port",
        type=PORT,
        default=WEB_VIEWER_PORT,
        metavar="PORT",
        help="headless: the port the web viewer is served on (HTTP)",
    )


def view_files(run_dir: Path, blueprint_path: Path) -> list[str]:
    """The run's recording, its analyses (`twin identify` logs under the same recording id: the viewer
    merges them) and a blueprint (.rbl) for the kind of run the directory holds, written to
    blueprint_path."""
    from twin.session import RRD_NAME
    from twin.viz.blueprint import kind_of_run, run_blueprint
    from twin.viz.rerun_log import look_target_of

    rrd = run_dir / RRD_NAME
    run_blueprint(kind_of_run(run_dir, look_target_of(rrd))).save(APPLICATION_ID, blueprint_path)
    return [str(rrd), *sorted(str(p) for p in run_dir.glob("*/*.rrd")), str(blueprint_path)]


def web_instructions(
    files: list[str], web_port: int = WEB_VIEWER_PORT, grpc_port: int = GRPC_PORT
) -> list[str]:
    """What to run without a display: the web viewer here, a tunnel from the user's machine."""
    quoted = " ".join(shlex.quote(f) for f in files)
    host = socket.gethostname() or "THIS_HOST"
    return [
        "No display here. Serve the recording to a browser from this machine:",
        f"  {shlex.quote(sys.executable)} -m rerun --serve-web {quoted} "
        f"--web-viewer-port {web_port} --port {grpc_port}",
        "then, on your own machine, forward both ports and open the viewer:",
        f"  ssh -N -L {web_port}:localhost:{web_port} -L {grpc_port}:localhost:{grpc_port} "
        f"{getpass.getuser()}@{host}",
        f"  http://localhost:{web_port}/?url=rerun%2Bhttp://localhost:{grpc_port}/proxy",
        "(the address the command prints is the one to open if it differs). Or copy the run directory to a "
        "machine with a display and run `twin view` there.",
    ]


def port_in_use(port: int) -> bool:
    """Whether something on this machine already listens on TCP `port` (a bind to it fails)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a closed socket's TIME_WAIT is free
        try:
            probe.bind(("", port))
        except OSError:
            return True
    return False


def cmd_view(args: argparse.Namespace) -> int:
    """`twin view DIR`: the Rerun viewer, or how to get one when there is no display."""
    from twin.session import RRD_NAME

    rrd = args.run_dir / RRD_NAME
    if not rrd.is_file():
        return fail(f"no Rerun recording at {rrd}")
    has_display = (
        sys.platform in ("darwin", "win32") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )
    if not has_display:  # the printed command would fail on a taken port: say so now, in one line
        if args.port == args.web_viewer_port:
            return fail(
                f"--port and --web-viewer-port are both {args.port}: the server and the viewer need one each"
            )
        for flag, port in (("--port", args.port), ("--web-viewer-port", args.web_viewer_port)):
            if port_in_use(port):
                return fail(f"port {port} is in use on this machine: pick a free one with {flag} PORT")
        # The blueprint must outlive this process: in a private directory of its own.
        private = Path(tempfile.mkdtemp(prefix="twin-view-"))  # mode 0700, a name nobody can plant
        blueprint = private / f"{args.run_dir.resolve().name or 'run'}.rbl"
        try:
            files = view_files(args.run_dir, blueprint)
        except Exception as exc:  # an unreadable .rrd: one line
            shutil.rmtree(private, ignore_errors=True)
            return fail(f"cannot read {rrd}: {exc}")
        print("\n".join(web_instructions(files, args.web_viewer_port, args.port)))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        try:
            files = view_files(args.run_dir, Path(tmp) / "blueprint.rbl")
        except Exception as exc:
            return fail(f"cannot read {rrd}: {exc}")
        viewer = shutil.which("rerun")
        port = ["--port", str(args.port)]
        cmd = [viewer, *port, *files] if viewer else [sys.executable, "-m", "rerun", *port, *files]
        return subprocess.call(cmd)


command = cmd_view
