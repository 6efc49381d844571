"""MuJoCo 4.0 against the 3.17 baseline, in one run: the rig with hand + tactile pads on every library foam
at both presets, each row timed under this tree (MuJoCo 4.0, calibrated foams) and under a baseline tree
with its own interpreter (the last commit on 3.17), interleaved row by row so a load change on the host
hits both alike. Targets: the fast preset >= 3x real time, the default >= 1x.

`python -m benchmarks.mujoco_upgrade --baseline-tree DIR --baseline-python PY` (the baseline: a checkout of
3bb531c and a venv with its pins, e.g. `git worktree add DIR 3bb531c`). run_all.py runs it only when
TWIN_BASELINE_TREE and TWIN_BASELINE_PYTHON name them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

DURATION_S = 10.0
CASES = [
    (name, fidelity)
    for fidelity in ("fast", "faithful")
    for name in ("block", "soft_block", "firm_block", "cylinder", "sphere")
]
_PROBE = """
import json, sys, time
from twin.experiments.compress import PHASES, CompressController
from twin.rig import Rig
from twin.sim.backend import SimBackend
from twin.sim.foam import LIBRARY
import mujoco
foam = LIBRARY[sys.argv[1]].with_overrides(fidelity=sys.argv[2])
backend = SimBackend(foam)
backend.connect()
t0 = time.perf_counter()
Rig(backend, phases=PHASES).run(CompressController(), float(sys.argv[3]))
wall = time.perf_counter() - t0
print(json.dumps({"rtf": float(sys.argv[3]) / wall, "mujoco": mujoco.__version__,
                  "warnings": backend.world.warnings()}))
"""


def _time(python: str, tree: str, name: str, fidelity: str) -> dict:
    env = os.environ | {"PYTHONPATH": tree, "MUJOCO_GL": "egl"}
    out = subprocess.run(
        [python, "-c", _PROBE, name, fidelity, str(DURATION_S)],
        cwd=tree, env=env, capture_output=True, text=True, check=True, timeout=600,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(quick: bool = False, baseline_tree: str = "", baseline_python: str = "") -> dict:
    """Each case under this tree, then under the baseline (default: $TWIN_BASELINE_TREE and
    $TWIN_BASELINE_PYTHON)."""
    baseline_tree = baseline_tree or os.environ["TWIN_BASELINE_TREE"]
    baseline_python = baseline_python or os.environ["TWIN_BASELINE_PYTHON"]
    here = str(Path(__file__).resolve().parents[1])
    rows = []
    for name, fidelity in CASES[:1] if quick else CASES:
        new = _time(sys.executable, here, name, fidelity)
        old = _time(baseline_python, baseline_tree, name, fidelity)
        rows.append({"object": name, "fidelity": fidelity, "new": new, "old": old})
        print(
            f"{name} {fidelity}: {new['rtf']:.2f}x ({new['mujoco']}) vs {old['rtf']:.2f}x ({old['mujoco']})"
        )
    return {"rows": rows, "duration_s": DURATION_S}


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    rows = results["rows"]
    lines = [
        "## MuJoCo 4.0 against 3.17 (rig + hand + tactile, real-time factor; targets: fast >= 3x, "
        "default >= 1x)",
        "",
        f"Compress procedure, {results['duration_s']:g} s of sim time per row, one process per row, the two "
        "versions interleaved row by row on the same host (`benchmarks/mujoco_upgrade.py`). 4.0 runs the "
        "calibrated foams (twin/sim/calibration.py); 3.17 the last commit before the upgrade.",
        "",
        "| object | preset | MuJoCo "
        + rows[0]["new"]["mujoco"]
        + " | MuJoCo "
        + rows[0]["old"]["mujoco"]
        + " | ratio | warnings (new) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        warn = ", ".join(f"{k}: {v}" for k, v in r["new"]["warnings"].items()) or "none"
        lines.append(
            f"| {r['object']} | {r['fidelity']} | {r['new']['rtf']:.2f}x | {r['old']['rtf']:.2f}x "
            f"| {r['new']['rtf'] / r['old']['rtf']:.2f} | {warn} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--baseline-tree", required=True)
    parser.add_argument("--baseline-python", required=True)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    results = run(baseline_tree=args.baseline_tree, baseline_python=args.baseline_python)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    print(to_markdown(results))


if __name__ == "__main__":
    main()
