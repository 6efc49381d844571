"""Run directory writer and reader, on real files: round trips, validation, crashes."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from twin.recording import (
    RAGGED,
    FieldSpec,
    Run,
    RunFormatError,
    RunWriter,
    StreamData,
    StreamSpec,
    open_run,
)

HAND = StreamSpec(
    name="hand",
    rate_hz=30.0,
    description="hand feedback",
    fields={
        "position_counts": FieldSpec(unit="counts", shape=(4,), dtype="int32", kind="raw"),
        "torque_nm": FieldSpec(unit="N*m", shape=(3,), kind="physical"),
        "broken_away": FieldSpec(unit="1", shape=(3,), dtype="bool", kind="truth"),
        "contact_xyz": FieldSpec(unit="m", shape=(2, 3), dtype="float32", kind="truth"),
    },
)
LOAD = StreamSpec(
    name="load",
    rate_hz=100.0,
    fields={
        "force_n": FieldSpec(unit="N", kind="physical", description="load cell"),
        "phase": FieldSpec(unit="1", dtype="int16", kind="status"),
    },
)
SCALAR = StreamSpec(name="s", rate_hz=10.0, fields={"x": FieldSpec(unit="m")})


def hand_row(i: int) -> dict:
    return {
        "position_counts": np.array([i, 2 * i, -3 * i, 17_000 + i], dtype=np.int64),
        "torque_nm": np.array([0.1 * i, -0.2 * i, 1e-9 * i]),
        "broken_away": np.array([i % 2 == 0, False, i > 20]),
        "contact_xyz": np.arange(6, dtype=np.float64).reshape(2, 3) * i,
    }


def write_two_rate_run(run_dir: Path, seconds: float = 1.0) -> None:
    """30 Hz hand and 100 Hz load samples, interleaved in time order, then closed."""
    events = [(i / 30.0, "hand", i) for i in range(round(30 * seconds))]
    events += [(i / 100.0, "load", i) for i in range(round(100 * seconds))]
    with RunWriter(run_dir, {"operator": "test", "gain": np.float32(0.5)}) as w:
        w.add_stream(HAND)
        w.add_stream(LOAD)
        for t, name, i in sorted(events):
            if name == "hand":
                w.append("hand", t, hand_row(i))
            else:
                w.append("load", t, {"force_n": np.sin(i), "phase": i // 10})


def test_round_trip_two_rates_preserves_values_dtypes_units(tmp_path):
    run_dir = tmp_path / "run"
    write_two_rate_run(run_dir)
    run = open_run(run_dir)

    assert run.status == "complete"
    assert run.metadata == {"operator": "test", "gain": 0.5}
    assert run.streams == {"hand": HAND, "load": LOAD}
    assert run.info["samples"] == {"hand": 30, "load": 100}
    assert run.info["error"] is None and "closed_utc" in run.info
    assert run.truncated == set()

    hand = run.stream("hand")
    assert len(hand) == 30
    np.testing.assert_array_equal(hand["t_s"], np.arange(30) / 30.0)
    expected = [hand_row(i) for i in range(30)]
    for name, fspec in HAND.fields.items():
        assert hand[name].dtype == np.dtype(fspec.dtype), name
        assert hand[name].shape == (30, *fspec.shape), name
        want = np.stack([row[name] for row in expected]).astype(fspec.dtype)
        np.testing.assert_array_equal(hand[name], want, err_msg=name)

    load = run.stream("load")
    assert load["force_n"].dtype == np.float64 and load["phase"].dtype == np.int16
    np.testing.assert_array_equal(load["force_n"], np.sin(np.arange(100)))
    np.testing.assert_array_equal(load["phase"], np.arange(100) // 10)


def test_summary_reports_counts_rates_and_units(tmp_path):
    write_two_rate_run(tmp_path / "run", seconds=2.0)
    summary = {row["name"]: row for row in open_run(tmp_path / "run").summary()}

    assert summary["hand"]["samples"] == 60 and summary["load"]["samples"] == 200
    assert summary["hand"]["rate_hz"] == 30.0
    assert summary["hand"]["measured_rate_hz"] == pytest.approx(30.0)
    assert summary["load"]["measured_rate_hz"] == pytest.approx(100.0)
    assert summary["load"]["duration_s"] == pytest.approx(1.99)
    assert summary["hand"]["fields"]["torque_nm"] == {
        "unit": "N*m",
        "kind": "physical",
        "shape": (3,),
        "dtype": "float64",
    }


def test_stream_files_are_plain_arrow_with_unit_metadata(tmp_path):
    write_two_rate_run(tmp_path / "run")
    with pa.ipc.open_stream(tmp_path / "run" / "streams" / "hand.arrows") as reader:
        table = reader.read_all()
    assert table.column_names == ["t_s", *HAND.fields]
    assert table.schema.metadata[b"stream"] == b"hand"
    assert float(table.schema.metadata[b"rate_hz"]) == 30.0
    torque = table.schema.field("torque_nm")
    assert torque.metadata[b"unit"] == b"N*m" and torque.metadata[b"kind"] == b"physical"
    assert json.loads(table.schema.field("contact_xyz").metadata[b"shape"]) == [2, 3]
    assert table.num_rows == 30
    assert table.column("contact_xyz")[1].as_py() == [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]


def test_spec_json_round_trip_and_rejections():
    assert StreamSpec.from_json(json.loads(json.dumps(HAND.to_json()))) == HAND
    with pytest.raises(ValueError, match="must match"):
        StreamSpec(name="Bad-Name", rate_hz=1.0, fields={})
    with pytest.raises(ValueError, match="must match"):
        StreamSpec(name="ok", rate_hz=1.0, fields={"Torque": FieldSpec(unit="N*m")})
    with pytest.raises(ValueError, match="implicit"):
        StreamSpec(name="ok", rate_hz=1.0, fields={"t_s": FieldSpec(unit="s")})
    with pytest.raises(ValueError, match="> 0"):
        StreamSpec(name="ok", rate_hz=0.0, fields={})
    with pytest.raises(ValueError, match="dtype"):
        FieldSpec(unit="m", dtype="complex128")
    with pytest.raises(ValueError, match="kind"):
        FieldSpec(unit="m", kind="guess")
    with pytest.raises(ValueError, match="shape"):
        FieldSpec(unit="m", shape=(0,))


def test_append_validation_errors_leave_the_stream_usable(tmp_path):
    w = RunWriter(tmp_path / "run", {})
    w.add_stream(HAND)
    row = hand_row(1)
    with pytest.raises(ValueError, match=r"unknown fields \['bogus'\]"):
        w.append("hand", 0.0, {**row, "bogus": 1.0})
    with pytest.raises(ValueError, match=r"missing fields \['torque_nm'\]"):
        w.append("hand", 0.0, {k: v for k, v in row.items() if k != "torque_nm"})
    with pytest.raises(ValueError, match=r"shape \(4,\), declared \(3,\)"):
        w.append("hand", 0.0, {**row, "torque_nm": np.zeros(4)})
    with pytest.raises(ValueError, match="does not fit int32"):
        w.append("hand", 0.0, {**row, "position_counts": [0.5, 0, 0, 0]})
    with pytest.raises(ValueError, match="unknown stream"):
        w.append("nope", 0.0, row)
    with pytest.raises(ValueError, match="already added"):
        w.add_stream(HAND)
    w.append("hand", 1.0, row)
    with pytest.raises(ValueError, match="before the previous"):
        w.append("hand", 0.5, row)
    w.append("hand", 1.0, row)  # equal timestamps are allowed
    with pytest.raises(ValueError, match="status"):
        w.close("done")
    w.close()
    np.testing.assert_array_equal(open_run(tmp_path / "run").stream("hand")["t_s"], [1.0, 1.0])


def test_run_dir_must_be_new_or_empty(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "old.txt").write_text("x")
    with pytest.raises(FileExistsError, match="not empty"):
        RunWriter(tmp_path / "full", {})
    (tmp_path / "file").write_text("x")
    with pytest.raises(FileExistsError, match="not a directory"):
        RunWriter(tmp_path / "file", {})
    (tmp_path / "empty").mkdir()
    RunWriter(tmp_path / "empty", {}).close()
    RunWriter(tmp_path / "a" / "b" / "new", {}).close()  # parents are created
    assert open_run(tmp_path / "a" / "b" / "new").status == "complete"


def test_context_manager_statuses(tmp_path):
    with RunWriter(tmp_path / "ok", {}) as w:
        w.add_stream(SCALAR)
    assert open_run(tmp_path / "ok").status == "complete"

    with pytest.raises(RuntimeError, match="motor stalled"), RunWriter(tmp_path / "bad", {}) as w:
        w.add_stream(SCALAR)
        w.append("s", 0.0, {"x": 1.0})
        raise RuntimeError("motor stalled")
    failed = open_run(tmp_path / "bad")
    assert failed.status == "failed" and failed.info["error"] == "motor stalled"
    assert len(failed.stream("s")) == 1  # rows buffered before the exception are kept

    with pytest.raises(KeyboardInterrupt), RunWriter(tmp_path / "ctrl_c", {}) as w:
        raise KeyboardInterrupt
    assert open_run(tmp_path / "ctrl_c").status == "interrupted"


def test_metadata_numpy_and_updates_are_json(tmp_path):
    w = RunWriter(tmp_path / "run", {"cal": np.arange(3), "k": np.int64(7), "p": tmp_path})
    w.update_metadata(foam="soft", gains=np.array([[1.0, 2.0]]))
    assert open_run(tmp_path / "run").metadata["gains"] == [[1.0, 2.0]]  # visible before close
    with pytest.raises(TypeError, match="not JSON-serialisable"):
        w.update_metadata(bad=object())
    w.close()
    run = open_run(tmp_path / "run")
    assert run.metadata == {
        "cal": [0, 1, 2],
        "k": 7,
        "p": str(tmp_path),
        "foam": "soft",
        "gains": [[1.0, 2.0]],
    }
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["run.json", "streams"]


def test_batches_written_on_run_time_span(tmp_path):
    w = RunWriter(tmp_path / "run", {}, flush_interval_s=1.0)
    w.add_stream(SCALAR)
    for i in range(10):
        w.append("s", i / 10, {"x": float(i)})
    live = open_run(tmp_path / "run")
    assert live.status == "running" and len(live.stream("s")) == 0  # 0.9 s < 1 s: buffered
    w.append("s", 1.0, {"x": 10.0})
    assert len(open_run(tmp_path / "run").stream("s")) == 11  # spans 1 s: written to the OS
    w.close()


def test_batches_written_on_wall_time_for_every_stream(tmp_path):
    w = RunWriter(tmp_path / "run", {}, flush_interval_s=0.2)
    w.add_stream(SCALAR)
    w.add_stream(LOAD)
    w.append("s", 0.0, {"x": 1.0})
    time.sleep(0.3)
    w.append("load", 0.0, {"force_n": 2.0, "phase": 0})  # any append checks every stream's age
    live = open_run(tmp_path / "run")
    assert len(live.stream("s")) == 1
    assert len(live.stream("load")) == 0
    w.flush()
    assert len(open_run(tmp_path / "run").stream("load")) == 1
    w.close()


def test_stream_added_mid_run(tmp_path):
    with RunWriter(tmp_path / "run", {}) as w:
        w.add_stream(SCALAR)
        w.append("s", 0.0, {"x": 1.0})
        assert list(open_run(tmp_path / "run").streams) == ["s"]
        w.add_stream(LOAD)
        w.append("load", 5.0, {"force_n": 2.0, "phase": 1})
    run = open_run(tmp_path / "run")
    assert len(run.stream("s")) == 1 and run.stream("load")["t_s"].tolist() == [5.0]


def test_cut_stream_file_recovers_complete_batches(tmp_path):
    w = RunWriter(tmp_path / "run", {})
    w.add_stream(SCALAR)
    w.add_stream(LOAD)
    path = tmp_path / "run" / "streams" / "s.arrows"
    sizes = []
    for batch in range(3):
        for i in range(4):
            w.append("s", batch + i / 10, {"x": float(10 * batch + i)})
        w.flush()
        sizes.append(path.stat().st_size)
    w.close()
    data = path.read_bytes()
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    del info["integrity"]  # as a writer killed before close leaves it: no digests, crash recovery
    (tmp_path / "run" / "run.json").write_text(json.dumps(info))

    path.write_bytes(data[: sizes[1] + 10])  # mid third batch
    run = open_run(tmp_path / "run")
    assert run.truncated == {"s"}
    np.testing.assert_array_equal(run.stream("s")["x"], [0, 1, 2, 3, 10, 11, 12, 13])
    assert run.stream("load")["t_s"].shape == (0,)  # never written: empty file, not truncated

    path.write_bytes(data[:5])  # mid schema message
    run = open_run(tmp_path / "run")
    empty = run.stream("s")
    assert run.truncated == {"s"} and len(empty) == 0
    assert empty["x"].dtype == np.float64 and empty.spec == SCALAR
    assert np.isnan(empty.measured_rate_hz())


def test_data_access_errors_name_what_exists(tmp_path):
    write_two_rate_run(tmp_path / "run")
    run = open_run(tmp_path / "run")
    with pytest.raises(KeyError, match="available: \\['hand', 'load'\\]"):
        run.stream("camera")
    with pytest.raises(KeyError, match="'t_s', 'force_n', 'phase'"):
        run.stream("load")["force"]
    assert isinstance(run, Run) and isinstance(run.stream("load"), StreamData)


@pytest.mark.parametrize(
    "damage",
    ["no_dir", "no_run_json", "corrupt_json", "wrong_format", "wrong_version", "bad_spec"],
)
def test_not_a_run_raises_run_format_error(tmp_path, damage):
    run_dir = tmp_path / "run"
    write_two_rate_run(run_dir)
    info_path = run_dir / "run.json"
    info = json.loads(info_path.read_text())
    if damage == "no_dir":
        run_dir = tmp_path / "missing"
    elif damage == "no_run_json":
        info_path.unlink()
    elif damage == "corrupt_json":
        info_path.write_text(info_path.read_text()[:40])
    elif damage == "wrong_format":
        info_path.write_text(json.dumps({**info, "format": "something-else"}))
    elif damage == "wrong_version":
        info_path.write_text(json.dumps({**info, "format_version": 99}))
    elif damage == "bad_spec":
        info["streams"]["hand"]["rate_hz"] = -1
        info_path.write_text(json.dumps(info))
    with pytest.raises(RunFormatError) as excinfo:
        open_run(run_dir)
    assert "\n" not in str(excinfo.value)
    assert isinstance(excinfo.value, ValueError)


def test_missing_stream_file_raises_run_format_error(tmp_path):
    write_two_rate_run(tmp_path / "run")
    (tmp_path / "run" / "streams" / "load.arrows").unlink()
    run = open_run(tmp_path / "run")
    assert len(run.stream("hand")) == 30
    with pytest.raises(RunFormatError, match=r"load\.arrows"):
        run.stream("load")


def test_sigkill_loses_at_most_the_flush_interval(tmp_path):
    run_dir = tmp_path / "run"
    helper = Path(__file__).with_name("_killed_writer.py")
    proc = subprocess.Popen([sys.executable, str(helper), str(run_dir)])
    try:
        deadline = time.monotonic() + 20.0
        while not (run_dir / "run.json").exists():
            assert proc.poll() is None, "writer exited early"
            assert time.monotonic() < deadline, "writer never created run.json"
            time.sleep(0.02)
        time.sleep(1.5)
        assert proc.poll() is None, "writer exited early"
        killed_wall = time.time()
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == -signal.SIGKILL

    run = open_run(run_dir)
    assert run.status == "running" and "closed_utc" not in run.info
    data = run.stream("fast")
    n = len(data)
    assert n > 0
    np.testing.assert_array_equal(data["index"], np.arange(n))  # contiguous from t = 0
    np.testing.assert_array_equal(data["t_s"], np.arange(n) / 200.0)
    np.testing.assert_allclose(data["xyz"][:, 2], 3 * data["t_s"])
    elapsed = killed_wall - run.metadata["start_wall_time_s"]
    assert elapsed - 1.0 <= data["t_s"][-1] <= elapsed


def test_ragged_fields_round_trip_across_batches_with_empty_rows(tmp_path):
    """Point clouds and encoded images: a varying leading dimension, empty rows included."""
    spec = StreamSpec(
        "surface",
        30.0,
        {
            "points_m": FieldSpec("m", (RAGGED, 3), "float32"),
            "jpeg": FieldSpec("byte", (RAGGED,), "uint8", kind="raw"),
            "count": FieldSpec("1", (), "int32", kind="status"),
        },
    )
    rng = np.random.default_rng(3)
    rows = [
        (rng.normal(size=(n, 3)).astype(np.float32), rng.integers(0, 256, m, dtype=np.uint8))
        for n, m in ((5, 7), (0, 0), (1, 3), (400, 1000))
    ]
    with RunWriter(tmp_path / "run", {}, flush_interval_s=1 / 30) as w:  # a batch every ~2 rows
        w.add_stream(spec)
        for k, (points, jpeg) in enumerate(rows):
            w.append("surface", k / 30, {"points_m": points, "jpeg": jpeg, "count": len(points)})
        with pytest.raises(ValueError, match="shape"):
            w.append("surface", 1.0, {"points_m": np.zeros((2, 2)), "jpeg": np.zeros(1), "count": 0})
    data = open_run(tmp_path / "run").stream("surface")
    assert len(data) == len(rows)
    for k, (points, jpeg) in enumerate(rows):
        np.testing.assert_array_equal(data["points_m"][k], points)
        assert data["points_m"][k].shape == (len(points), 3)
        np.testing.assert_array_equal(data["jpeg"][k], jpeg)
        assert data["jpeg"][k].dtype == np.uint8
    np.testing.assert_array_equal(data["count"], [5, 0, 1, 400])
    with pytest.raises(ValueError, match="ragged"):
        FieldSpec("m", (3, RAGGED))


def test_a_stream_prints_as_a_summary_not_its_arrays(tmp_path):
    """print(run.stream(...)): name, samples, time span and rate, one line per column with its shape
    (n, per-sample shape), dtype, unit and kind; no array data, however long the stream."""
    write_two_rate_run(tmp_path / "run", seconds=10.0)
    hand = open_run(tmp_path / "run").stream("hand")
    lines = str(hand).splitlines()
    assert repr(hand) == str(hand)
    assert lines[0] == "StreamData 'hand': 300 samples, t = 0.000 to 9.967 s, 30 Hz (declared 30 Hz)"
    assert [line.split() for line in lines[1:]] == [
        ["t_s", "(300,)", "float64", "s", "time"],
        ["position_counts", "(300,", "4)", "int32", "counts", "raw"],
        ["torque_nm", "(300,", "3)", "float64", "N*m", "physical"],
        ["broken_away", "(300,", "3)", "bool", "1", "truth"],
        ["contact_xyz", "(300,", "2,", "3)", "float32", "m", "truth"],
    ]
    assert len(str(hand)) < 600


def test_a_ragged_or_empty_stream_prints_its_shape_and_no_span(tmp_path):
    points = StreamSpec(
        name="cloud", rate_hz=30.0, fields={"points_m": FieldSpec(unit="m", shape=(RAGGED, 3))}
    )
    with RunWriter(tmp_path / "run", {}) as w:
        w.add_stream(points)
        w.add_stream(SCALAR)
        for i in range(3):
            w.append("cloud", i / 30, {"points_m": np.zeros((i + 1, 3))})
    run = open_run(tmp_path / "run")
    assert str(run.stream("cloud")).splitlines()[-1].split() == [
        "points_m",
        "(3,",
        "k,",
        "3)",
        "float64",
        "m",
        "physical",
    ]
    assert str(run.stream("s")).splitlines()[0] == "StreamData 's': no samples (declared 10 Hz)"
