"""What a run directory promises (issue 18): stream files checked against the digests recorded at
close, run.json's counts reconciled with what is readable, warnings kept, and a run directory removed
or replaced mid-run stopping the writer, which never writes into the replacement."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from twin.interface.errors import RunDirectoryLostError, TwinError
from twin.recording import RunFormatError, RunWriter, open_run

from .test_recording import HAND, LOAD, hand_row, write_two_rate_run

TWIN = [sys.executable, "-m", "twin.cli"]


def test_a_closed_run_records_each_stream_files_size_and_sha256(tmp_path):
    write_two_rate_run(tmp_path / "run")
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["integrity"]["algorithm"] == "sha256"
    for name in ("hand", "load"):
        recorded = info["integrity"]["streams"][name]
        assert recorded["bytes"] == (tmp_path / "run" / "streams" / f"{name}.arrows").stat().st_size
        assert len(recorded["sha256"]) == 64
    run = open_run(tmp_path / "run")
    assert run.corrupt_streams() == {} and run.sample_mismatches() == {}


def test_one_flipped_byte_in_a_stream_file_is_refused_in_one_line(tmp_path):
    write_two_rate_run(tmp_path / "run")
    path = tmp_path / "run" / "streams" / "hand.arrows"
    data = bytearray(path.read_bytes())
    data[-200] ^= 0x01  # inside the last record batch's values: Arrow itself would not notice
    path.write_bytes(bytes(data))
    run = open_run(tmp_path / "run")
    with pytest.raises(RunFormatError, match=r"hand\.arrows is corrupt") as raised:
        run.stream("hand")
    assert len(str(raised.value).splitlines()) == 1
    assert isinstance(raised.value, TwinError)  # the CLI's one-line path
    assert set(run.corrupt_streams()) == {"hand"}
    assert len(run.stream("load")) == 100  # the intact stream still reads


def test_a_killed_writers_run_has_no_digests_and_reads_with_crash_recovery(tmp_path):
    w = RunWriter(tmp_path / "run", {})
    w.add_stream(HAND)
    for i in range(5):
        w.append("hand", i / 30, hand_row(i))
    w.flush()  # never closed: as a SIGKILL leaves it
    run = open_run(tmp_path / "run")
    assert run.status == "running" and run.digests == {}
    assert len(run.stream("hand")) == 5
    assert run.sample_mismatches() == {"hand": (0, 5)}  # run.json counted before the samples came


def test_samples_run_json_recorded_against_samples_readable(tmp_path):
    write_two_rate_run(tmp_path / "run")
    info_path = tmp_path / "run" / "run.json"
    info = json.loads(info_path.read_text())
    assert info["samples"] == {"hand": 30, "load": 100}
    info["samples"]["load"] = 120
    del info["integrity"]
    info_path.write_text(json.dumps(info))
    assert open_run(tmp_path / "run").sample_mismatches() == {"load": (120, 100)}


def test_warnings_are_kept_beside_a_complete_status(tmp_path):
    with RunWriter(tmp_path / "run", {}) as w:
        w.add_stream(LOAD)
        w.warn("hand loop ran at 16.3 Hz of 30 Hz (10 s of run time took 18.4 s)")
    run = open_run(tmp_path / "run")
    assert run.status == "complete"
    assert run.warnings == ["hand loop ran at 16.3 Hz of 30 Hz (10 s of run time took 18.4 s)"]


def test_malformed_integrity_or_warnings_are_format_errors(tmp_path):
    write_two_rate_run(tmp_path / "run")
    info_path = tmp_path / "run" / "run.json"
    good = json.loads(info_path.read_text())
    bad = (("integrity", {"streams": []}), ("integrity", "x"), ("warnings", "x"), ("warnings", [1]))
    for key, value in bad:
        info_path.write_text(json.dumps({**good, key: value}))
        with pytest.raises(RunFormatError, match=key):
            open_run(tmp_path / "run")


def _writer_with_rows(run_dir: Path) -> RunWriter:
    w = RunWriter(run_dir, {}, flush_interval_s=0.01)
    w.add_stream(LOAD)
    w.append("load", 0.0, {"force_n": 1.0, "phase": 0})
    return w


def _append_until_lost(w: RunWriter) -> None:
    """Keep recording, as a run does, until the writer notices (a hang guard, not a timing check)."""
    deadline = time.monotonic() + 30
    t = 0.0
    while time.monotonic() < deadline:
        t += 0.01
        w.append("load", t, {"force_n": 1.0, "phase": 0})
        time.sleep(0.002)
    raise AssertionError("the writer never noticed its directory was gone")


@pytest.mark.parametrize("how", ["removed", "replaced", "moved"])
def test_a_run_directory_gone_mid_run_stops_the_writer_and_nothing_reaches_a_replacement(tmp_path, how):
    run_dir = tmp_path / "run"
    w = _writer_with_rows(run_dir)
    if how == "moved":
        run_dir.rename(tmp_path / "elsewhere")
    else:
        shutil.rmtree(run_dir)
    if how != "removed":
        run_dir.mkdir()
        (run_dir / "theirs.txt").write_text("someone else's")
    with pytest.raises(RunDirectoryLostError, match="removed or replaced during the run"):
        _append_until_lost(w)
    with pytest.raises(RunDirectoryLostError, match=r"run\.json was not written"):
        w.close("failed", "whatever")
    if how == "removed":
        assert not run_dir.exists()
    else:
        assert sorted(os.listdir(run_dir)) == ["theirs.txt"]
    if how == "moved":  # the moved directory keeps a "running" run.json: never claimed complete
        assert json.loads((tmp_path / "elsewhere" / "run.json").read_text())["status"] == "running"


def test_a_replaced_run_directory_is_noticed_at_close_too(tmp_path):
    run_dir = tmp_path / "run"
    w = RunWriter(run_dir, {})
    w.add_stream(LOAD)
    w.append("load", 0.0, {"force_n": 1.0, "phase": 0})
    shutil.rmtree(run_dir)
    run_dir.mkdir()
    with pytest.raises(RunDirectoryLostError):
        w.close("complete")
    assert os.listdir(run_dir) == []


@pytest.mark.slow
@pytest.mark.parametrize("replace", [False, True])
def test_twin_run_with_its_out_directory_removed_mid_run_fails_in_one_line(tmp_path, replace):
    """`twin run compress` whose --out directory is deleted (or deleted and made again by someone
    else) while it runs: non-zero exit, one error line, and nothing written into the replacement."""
    proc = subprocess.Popen(
        [*TWIN, "run", "compress", "--duration", "60", "--out", "run", "--no-progress"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    hand = tmp_path / "run" / "streams" / "hand.arrows"
    deadline = time.monotonic() + 60
    while not (hand.exists() and hand.stat().st_size > 0) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert hand.exists(), "the run never started"
    shutil.rmtree(tmp_path / "run")
    if replace:
        (tmp_path / "run").mkdir()
        (tmp_path / "run" / "theirs.txt").write_text("someone else's")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode not in (0, None), (out, err)
    assert "run complete" not in out and "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "removed or replaced during the run" in lines[0], err
    if replace:
        assert os.listdir(tmp_path / "run") == ["theirs.txt"]
    else:
        assert not (tmp_path / "run").exists()
