"""Run benchmarks and write BENCHMARKS.md with the machine they ran on.

Usage: python benchmarks/run_all.py [--quick] [--only realtime,foam_fidelity,serial_cycle]
Each section sits between markers, so --only re-runs some sections and keeps the others as they were.
"""

from __future__ import annotations

import argparse
import importlib
import os
import platform
import re
import signal
import sys
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SECTIONS = (
    "mujoco_upgrade",
    "realtime",
    "foam_calibration",
    "foam_fidelity",
    "scan_foams",
    "fem_condensation",
    "serial_cycle",
    "emulator_latency",
    "bridge_under_load",
    "camera_bridge",
    "tactile_sensors",
    "stereo_calibration",
    "stereo_pipeline",
    "stereo_run",
    "recording_size",
    "identification",
    "identification_cameras",
    "identification_hardware",
    "identification_hardware_numbered",
    "interval_calibration",
    "identifiability",
    "grasp_scatter",
    "round_tops",
    "nu_from_cameras",
    "nu_reference",
    "identify_speed",
    "shape_network",
    "sweep_throughput",
    "run_overhead",
    "env_throughput",
    "rl_learning",
)


def machine() -> str:
    """One paragraph naming the machine, for every figure below it."""
    cpu = platform.processor() or "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import mujoco

    return (
        f"Machine: {cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, "
        f"Python {platform.python_version()}, MuJoCo {mujoco.__version__}. "
        f"Written {datetime.now(UTC):%Y-%m-%d %H:%M} UTC by `python benchmarks/run_all.py`."
    )


def read_sections(path: Path) -> dict[str, str]:
    """The sections of an existing BENCHMARKS.md, by name (empty if there is none)."""
    if not path.exists():
        return {}
    found = re.findall(r"<!-- section:(\w+) -->\n(.*?)<!-- /section:\1 -->", path.read_text(), flags=re.S)
    return dict(found)


def read_preamble(path: Path) -> str:
    """What an existing BENCHMARKS.md says before its first section (its title and notes that span
    sections), kept as it is; a new file gets the title alone."""
    if not path.exists():
        return "# Benchmarks\n\n"
    return path.read_text().split("<!-- section:", 1)[0]


def main() -> int:
    """Run the chosen sections and write BENCHMARKS.md."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="tiny settings (smoke test, not for the record)")
    parser.add_argument("--only", default=",".join(SECTIONS))
    parser.add_argument("--out", type=Path, default=ROOT / "BENCHMARKS.md")
    args = parser.parse_args()
    os.environ.setdefault("MUJOCO_GL", "egl")
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        # A background job of a script starts with Ctrl-C ignored, and so would the emulators the
        # benchmarks stop with it (camera_bridge's once kept rendering for 600 s beside the next ones).
        signal.signal(signal.SIGINT, signal.default_int_handler)
    sys.path.insert(0, str(ROOT))
    sections, preamble = read_sections(args.out), read_preamble(args.out)
    for name in args.only.split(","):
        module = importlib.import_module(f"benchmarks.{name}")
        print(f"running {name} ...", file=sys.stderr, flush=True)
        results = module.run(quick=args.quick)
        sections[name] = f"{machine()}\n\n{module.to_markdown(results)}"
        if hasattr(module, "plot"):
            module.plot(results, str(ROOT / "benchmarks" / f"{name}.png"))
    body = [f"<!-- section:{n} -->\n{sections[n]}<!-- /section:{n} -->\n" for n in SECTIONS if n in sections]
    args.out.write_text(preamble + "\n".join(body))
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
