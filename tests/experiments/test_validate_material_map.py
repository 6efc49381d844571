"""The unseen-foam check simulates, identifies and scores runs the mapping never saw."""

import re
from pathlib import Path

from experiments.validate_material_map import FIRST_SEED, main


def test_one_unseen_foam_is_simulated_identified_and_scored(tmp_path: Path, capsys):
    argv = ["--sizes-mm", "70", "--per-size", "1", "--soft-per-size", "0", "--workers", "1"]
    assert main([*argv, "--keep-runs", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    (run,) = tmp_path.iterdir()
    assert run.name.startswith("sphere-70mm-") and run.name.endswith(f"-s{FIRST_SEED + 1}")
    young_kpa = int(run.name.split("-")[2][:-2]) / 1e3
    line = re.search(r"70\.0 mm +([\d.]+) kPa +seed \d+: +([+-][\d.]+) %", out)
    assert line and float(line[1]) == round(young_kpa, 1)
    assert abs(float(line[2])) < 10  # a foam inside the mapping's range, away from the soft end
    assert "1 of 1 runs estimated" in out
    # Kept runs are reused, not simulated again: the same figures, the same single run.
    assert main([*argv, "--keep-runs", str(tmp_path)]) == 0
    assert capsys.readouterr().out == out and len(list(tmp_path.iterdir())) == 1
