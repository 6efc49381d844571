"""RunWriter's batched declarations and final metadata (issue 19: a run rewrites run.json less often)."""

import json

import numpy as np
import pytest

from twin.recording import FieldSpec, RunWriter, StreamSpec, open_run

A = StreamSpec(name="a", rate_hz=30.0, fields={"x": FieldSpec(unit="m", shape=(3,))})
B = StreamSpec(name="b", rate_hz=30.0, fields={"n": FieldSpec(unit="1", dtype="int32")})


def test_streams_declared_together_are_all_recorded(tmp_path):
    with RunWriter(tmp_path / "run", {}) as w:
        w.add_streams(A, B)
        w.append("a", 0.0, {"x": [1.0, 2.0, 3.0]})
        w.append("b", 0.0, {"n": 7})
    run = open_run(tmp_path / "run")
    assert set(run.streams) == {"a", "b"}
    np.testing.assert_array_equal(run.stream("a")["x"], [[1.0, 2.0, 3.0]])
    assert run.stream("b")["n"].tolist() == [7]


def test_a_bad_stream_among_several_adds_none(tmp_path):
    w = RunWriter(tmp_path / "run", {})
    with pytest.raises(ValueError, match="'a' already added"):
        w.add_streams(A, B, A)
    with pytest.raises(TypeError):
        w.add_streams(B, "not a spec")
    assert json.loads((tmp_path / "run" / "run.json").read_text())["streams"] == {}
    w.add_streams(A, B)  # nothing was half-declared: both can still be added
    w.close()
    assert set(open_run(tmp_path / "run").streams) == {"a", "b"}


def test_close_writes_its_metadata_with_the_final_status(tmp_path):
    w = RunWriter(tmp_path / "run", {"operator": "test"})
    w.add_stream(A)
    w.close("failed", "stopped", metadata={"final_phase": "compress", "gain": np.float32(0.5)})
    run = open_run(tmp_path / "run")
    assert run.status == "failed" and run.metadata["operator"] == "test"
    assert run.metadata["final_phase"] == "compress" and run.metadata["gain"] == 0.5


def test_a_value_changed_after_append_is_recorded_as_appended(tmp_path):
    value = np.array([1.0, 2.0, 3.0])  # already the declared dtype: kept as a copy all the same
    with RunWriter(tmp_path / "run", {}) as w:
        w.add_stream(A)
        w.append("a", 0.0, {"x": value})
        value[:] = -1.0
    np.testing.assert_array_equal(open_run(tmp_path / "run").stream("a")["x"], [[1.0, 2.0, 3.0]])
