"""benchmarks/identification_cameras.py keeps its word on a restart and scores what it says: finished
rows are taken back in the draw's order (shapes in turn, each shape's draws until enough are held), and
a run refused without an interval counts against the coverage."""

import json
from datetime import UTC, datetime, timedelta

from benchmarks import identification as hidden
from benchmarks import identification_cameras as cams


def test_a_restart_takes_the_finished_rows_in_turn_and_runs_nothing_past_the_clock(tmp_path):
    candidates = hidden.draw_cases(hidden.CANDIDATES, tmp_path, 2999, 29900)
    first = {s: [c for c in candidates if c["shape"] == s] for s in hidden.SHAPES}
    written = []
    for shape, held in (("block", [True]), ("cylinder", [False, True]), ("sphere", [True])):
        for case, was_held in zip(first[shape], held, strict=False):
            row = {k: case[k] for k in cams.CASE_KEYS} | {"case": cams.case_name(case), "method": "cameras"}
            written.append(row | {"held": was_held, "case_s": 1.0})
    written.append(written[0] | {"method": "tolerated"})  # another method's row: not this one's
    (tmp_path / cams.ROWS_FILE).write_text("".join(json.dumps(r) + "\n" for r in written))
    past = datetime.now(UTC) - timedelta(minutes=1)

    rows = cams.draw(1, tmp_path, "cameras", past, 2999, 29900)

    assert [(r["case"], r["held"]) for r in rows] == [
        (cams.case_name(first["block"][0]), True),
        (cams.case_name(first["cylinder"][0]), False),
        (cams.case_name(first["cylinder"][1]), True),
        (cams.case_name(first["sphere"][0]), True),
    ]
    assert not any(p.is_dir() for p in tmp_path.iterdir())  # no run was started after the clock


def test_the_coverage_counts_a_run_refused_without_an_interval_as_a_miss():
    truth = {"young_pa": 40e3, "held": True, "case_s": 1.0}
    number = hidden._score(truth | {"estimate_pa": 41e3, "ci95_pa": [37e3, 45e3]})
    only = hidden._score(truth | {"refused": "wide", "interval_only_pa": [20e3, 35e3], "withheld_pa": 30e3})
    refused = truth | {"refused": "too few like grasps"}

    s = cams.summary([number, only, refused])

    assert (s["numbers"], s["interval_only"], s["refused"]) == (1, 1, 1)
    assert s["covered"] == 1  # the number holds 40 kPa; the lone interval misses it; the third has none
    assert s["median"] == s["max"] == abs(41e3 / 40e3 - 1)
