"""`twin export --format parquet`: one table per stream, read back with pyarrow against the runs."""

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

import twin
from twin.cli import main


def _column(table, name: str) -> np.ndarray:
    return np.array(table.column(name).to_pylist())


def test_parquet_tables_hold_every_stream_of_every_run(runs, tmp_path: Path):
    out = tmp_path / "tables"
    argv = ["export", str(runs["plain"]), str(runs["cam"]), "--format", "parquet", "--out", str(out)]
    assert main(argv) == 0
    hand = pq.read_table(out / "hand.parquet")
    for episode, name in enumerate(("plain", "cam")):
        recorded = twin.open_run(runs[name]).stream("hand")
        mine = _column(hand, "episode_index") == episode
        assert np.array_equal(_column(hand, "position_counts")[mine], recorded["position_counts"])
        assert np.array_equal(_column(hand, "t_s")[mine], recorded.t_s)
    stereo = pq.read_table(out / "stereo.parquet")
    assert set(stereo.column("run").to_pylist()) == {"cam"}
    assert json.loads((out / "runs.json").read_text())[1]["metadata"]["backend"] == "sim"
