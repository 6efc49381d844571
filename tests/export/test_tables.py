"""`twin export --format parquet`: one table per stream whose columns keep their meaning (unit and
description in the Arrow field metadata and the file's key-value metadata, the stream specs in
runs.json), one join key across a run's tables (the documented join, run as docs/api.md writes it),
and a run id that tells apart runs of one directory name; read back with pyarrow against the runs."""

import json
import re
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

import twin
from tests.export.conftest import write_off_grid_run
from twin.cli import main

API_MD = Path(__file__).resolve().parents[2] / "docs" / "api.md"


def _column(table, name: str) -> np.ndarray:
    return np.array(table.column(name).to_pylist())


def _export(runs: dict[str, Path], names: tuple[str, ...], out: Path) -> Path:
    assert main(["export", *(str(runs[n]) for n in names), "--format", "parquet", "--out", str(out)]) == 0
    return out


def test_parquet_tables_hold_every_stream_of_every_run(runs, tmp_path: Path):
    out = _export(runs, ("plain", "cam"), tmp_path / "tables")
    hand = pq.read_table(out / "hand.parquet")
    for episode, name in enumerate(("plain", "cam")):
        recorded = twin.open_run(runs[name]).stream("hand")
        mine = _column(hand, "episode_index") == episode
        assert np.array_equal(_column(hand, "position_counts")[mine], recorded["position_counts"])
        assert np.array_equal(_column(hand, "t_s")[mine], recorded.t_s)
    stereo = pq.read_table(out / "stereo.parquet")
    assert set(stereo.column("run").to_pylist()) == {"cam"}
    assert json.loads((out / "runs.json").read_text())[1]["metadata"]["backend"] == "sim"


def test_every_column_carries_the_unit_and_description_the_recorder_declared(runs, tmp_path: Path):
    out = _export(runs, ("plain", "cam"), tmp_path / "tables")
    index = json.loads((out / "runs.json").read_text())
    recorded = json.loads((runs["cam"] / "run.json").read_text())["streams"]
    assert index[1]["streams"] == recorded  # runs.json: each run's stream specs, as run.json has them
    for path in sorted(out.glob("*.parquet")):
        stream = path.stem
        schema = pq.read_schema(path)
        kv = pq.read_metadata(
            path
        ).metadata  # the file's key-value metadata: what DuckDB's parquet_kv_metadata lists
        assert kv[b"stream"].decode() == stream
        for name in schema.names:
            meta = schema.field(name).metadata
            assert meta[b"unit"] and meta[b"description"], (stream, name)
            assert kv[f"unit:{name}".encode()] == meta[b"unit"]
            assert kv[f"description:{name}".encode()] == meta[b"description"]
            if name in recorded[stream]["fields"]:
                spec = recorded[stream]["fields"][name]
                assert meta[b"unit"].decode() == spec["unit"] and meta[b"kind"].decode() == spec["kind"]
                assert json.loads(meta[b"shape"]) == spec["shape"]
    hand = pq.read_schema(out / "hand.parquet")
    assert hand.field("velocity_counts").metadata[b"unit"] == b"counts/0.01s"  # per 10 ms, as the BH8 counts
    assert hand.field("t_s").metadata[b"unit"] == b"s"


def test_the_documented_join_of_hand_and_command_returns_every_row(runs, tmp_path: Path, monkeypatch):
    text = API_MD.read_text().split("\n## Export\n", 1)[1].split("\n## ", 1)[0]
    (example,) = [b for b in re.findall(r"```python\n(.*?)```", text, flags=re.S) if "hand_sample" in b]
    monkeypatch.chdir(tmp_path)
    _export(runs, ("plain", "cam"), tmp_path / "tables/squeeze")
    scope: dict = {}
    exec(compile(example, "docs/api.md: Export", "exec"), scope)
    hand, command, pairs = scope["hand"], scope["command"], scope["pairs"]
    assert len(pairs) == len(hand) == len(command) > 100  # every reading, every command, each once
    assert sorted(pairs.column("hand_row").to_pylist()) == list(range(len(hand)))
    assert sorted(pairs.column("command_row").to_pylist()) == list(range(len(command)))
    reading_t = _column(hand, "t_s")[_column(pairs, "hand_row")]
    sent_t = _column(command, "t_s")[_column(pairs, "command_row")]
    assert np.allclose(sent_t - reading_t, 0.004)  # the sim's latency: a join on t_s matches nothing
    assert np.array_equal(
        np.asarray(scope["set_point"].to_pylist()),
        _column(command, "position_counts")[_column(pairs, "command_row")],
    )
    for episode, name in enumerate(("plain", "cam")):  # the pairs: each reading and the command answering it
        run = twin.open_run(runs[name])
        mine = _column(hand, "episode_index")[_column(pairs, "hand_row")] == episode
        assert np.array_equal(np.sort(reading_t[mine]), run.stream("hand").t_s)
        assert np.array_equal(np.sort(sent_t[mine]), run.stream("command").t_s)


def test_a_scan_or_frame_joins_the_latest_reading_at_or_before_it(runs, tmp_path: Path):
    out = _export(runs, ("cam",), tmp_path / "tables")
    hand_t = _column(pq.read_table(out / "hand.parquet"), "t_s")
    for stream in ("tactile", "stereo", "stereo_truth", "truth", "command"):
        table = pq.read_table(out / f"{stream}.parquet")
        key, t_s = _column(table, "hand_sample"), _column(table, "t_s")
        assert table.column("hand_sample").null_count == 0, stream
        assert (hand_t[key] <= t_s).all(), stream
        later = key + 1 < len(hand_t)
        assert (hand_t[key[later] + 1] > t_s[later]).all(), stream


def test_runs_of_one_directory_name_keep_apart(runs, tmp_path: Path):
    out = _export(runs, ("plain", "off_grid"), tmp_path / "tables")
    hand = pq.read_table(out / "hand.parquet")
    ids = [json.loads((runs[n] / "run.json").read_text())["run_id"] for n in ("plain", "off_grid")]
    assert ids[0] != ids[1]
    for episode, (run_id, name) in enumerate(zip(ids, ("plain", "hardware/plain"), strict=True)):
        mine = _column(hand, "episode_index") == episode
        assert set(_column(hand, "run_id")[mine]) == {run_id} and set(_column(hand, "run")[mine]) == {name}
    index = json.loads((out / "runs.json").read_text())
    assert [(r["run_id"], r["run"]) for r in index] == list(
        zip(ids, ("plain", "hardware/plain"), strict=True)
    )


def test_runs_that_recorded_a_field_in_different_units_are_refused(runs, tmp_path: Path, capsys):
    other = write_off_grid_run(tmp_path / "fast", velocity_unit="counts/2.56e-05s")
    argv = ["export", str(runs["off_grid"]), str(other), "--format", "parquet", "--out", str(tmp_path / "t")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "hand.velocity_counts: unit counts/0.01s in" in err and "2.56e-05" in err
    assert not (tmp_path / "t").exists()
