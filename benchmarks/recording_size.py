"""What a run's Rerun recording (run.rrd) costs per minute, with and without the cameras, and what in it.

Each row is `twin run compress` on the default block (sim), once for `SHORT_S` and once for `LONG_S` of
sim time: the growth between the two, per minute, is what a longer run adds (the static part, the
model and the blueprint, cancels). The breakdown names the entities that grow most, by their Arrow
bytes as Rerun's own reader returns them (`rerun.chunk.RrdReader`: the file itself is LZ4-compressed,
so the shares are of the uncompressed data).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from twin.experiments.compress import PHASES, CompressController

from twin.session import RRD_NAME, run_experiment
from twin.sim.backend import SimBackend
from twin.sim.foam import DEFAULT_OBJECT, LIBRARY

SHORT_S, LONG_S = 6.0, 12.0
TOP = 6
BEFORE_MB_PER_MIN = {False: 8.3, True: 39.5}
"""This script's figures on commit b82e7d1, before issue 39's lean (the fused cloud and mesh at 5 Hz, a
blueprint sent when the data started): the reference each row is set against."""
"""Entities (grouped under their parent for the bodies, pads and plots) listed in the breakdown."""


def _group(entity: str) -> str:
    """An entity's line in the breakdown: the bodies, the pads and each plot stream as one each."""
    for prefix in ("/world/bodies/", "/tactile/", "/plots/"):
        if entity.startswith(prefix):
            rest = entity.removeprefix(prefix).split("/")
            return prefix + ("*" if prefix != "/plots/" else f"{rest[0]}/*")
    return entity


def _entity_bytes(rrd: Path) -> dict[str, int]:
    """Arrow bytes of the time-varying rows of each entity group of an .rrd."""
    from rerun.chunk import RrdReader

    out: dict[str, int] = {}
    for chunk in RrdReader(rrd).stream().filter(is_static=False):
        batch = chunk.to_record_batch()
        out[_group(chunk.entity_path)] = out.get(_group(chunk.entity_path), 0) + batch.nbytes
    return out


def _run(cameras: bool, duration_s: float, tmp: Path) -> tuple[float, dict[str, int]]:
    run_dir = tmp / f"run-{'cameras' if cameras else 'plain'}-{duration_s:g}"
    run_experiment(
        backend=SimBackend(LIBRARY[DEFAULT_OBJECT], stereo=cameras),
        controller=CompressController(),
        phases=PHASES,
        duration_s=duration_s,
        run_dir=run_dir,
        experiment={"name": "compress"},
        argv=["benchmark"],
    )
    rrd = run_dir / RRD_NAME
    return rrd.stat().st_size / 1e6, _entity_bytes(rrd)


def run(quick: bool = False) -> dict:
    """MB of run.rrd for a short and a long run, with and without cameras; growth per minute."""
    short, long = (1.0, 2.0) if quick else (SHORT_S, LONG_S)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for cameras in (False, True):
            mb_short, bytes_short = _run(cameras, short, Path(tmp))
            mb_long, bytes_long = _run(cameras, long, Path(tmp))
            growth = {k: bytes_long.get(k, 0) - bytes_short.get(k, 0) for k in bytes_long}
            total = sum(growth.values()) or 1
            top = sorted(growth.items(), key=lambda kv: -kv[1])[:TOP]
            rows.append(
                {
                    "cameras": cameras,
                    "short_mb": mb_short,
                    "long_mb": mb_long,
                    "mb_per_min": (mb_long - mb_short) / (long - short) * 60.0,
                    "top": [(k, v / total) for k, v in top],
                }
            )
    return {"short_s": short, "long_s": long, "object": DEFAULT_OBJECT, "rows": rows}


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    short, long = results["short_s"], results["long_s"]
    lines = [
        "## The Rerun recording's size (run.rrd, MB per minute of run)",
        "",
        f"`twin run compress` on the {results['object']} (sim) for {short:g} s and {long:g} s of sim time "
        f"(`benchmarks/recording_size.py`): the growth between the two, per minute. *Largest*: the "
        "entities that grow most, as shares of the growth's uncompressed Arrow bytes (Rerun's reader). "
        "*Before*: the same script on b82e7d1, where the fused cloud and mesh went to the .rrd at 5 Hz (now "
        "2 Hz: `FUSED_PERIOD_S`); the runs since also plot eq. 6 and the observer minus the truth.",
        "",
        f"| run | {short:g} s | {long:g} s | MB per minute | before (b82e7d1) | largest |",
        "|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        top = ", ".join(f"`{k}` {share:.0%}" for k, share in r["top"])
        lines.append(
            f"| {'with cameras' if r['cameras'] else 'no cameras'} | {r['short_mb']:.2f} MB "
            f"| {r['long_mb']:.2f} MB | {r['mb_per_min']:.1f} "
            f"| {BEFORE_MB_PER_MIN[r['cameras']]:.1f} | {top} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
