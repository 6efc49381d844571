"""Hostile files and places, through the real `twin` command (issue 37): crafted run.json keys and
nesting, rig.toml calibration paths, planted symlinks, concurrent and repeated exports, runs that never
closed, read-only and full places, names too long. Each must end in one line, the right exit status,
and nothing written outside --out. The runs are written by the real RunWriter (no simulation: fast)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from twin.recording import RunFormatError, RunWriter, open_run
from twin.rig import command_stream_spec, hand_stream_spec

TWIN = [sys.executable, "-m", "twin.cli"]


def twin(*args: str, cwd: Path, env: dict | None = None, **kwargs) -> subprocess.CompletedProcess:
    environ = {**os.environ, "MUJOCO_GL": "egl", **(env or {})}
    environ.pop("DISPLAY", None)
    return subprocess.run(
        [*TWIN, *args], cwd=cwd, capture_output=True, text=True, env=environ, timeout=120, **kwargs
    )


def one_line(result: subprocess.CompletedProcess, status: int = 2) -> str:
    """The command failed with `status` and exactly one `twin: error:` line, no traceback."""
    assert result.returncode == status, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twin: error: "), result.stderr
    return lines[0]


def write_run(path: Path, status: str | None = "complete", samples: int = 5) -> Path:
    """A small real run: hand and command streams at 30 Hz; `status` None leaves it open (running)."""
    writer = RunWriter(path, {"experiment": {"name": "compress", "object": "block"}, "backend": "sim"})
    writer.add_streams(hand_stream_spec(30.0, "counts"), command_stream_spec(30.0))
    for k in range(samples):
        t = k / 30.0
        writer.append(
            "hand",
            t,
            {
                "position_counts": np.full(4, 100 * k),
                "velocity_counts": np.zeros(4),
                "strain_counts": np.full(3, 128),
                "position_rad": np.zeros(4),
                "velocity_rad_s": np.zeros(4),
                "torque_nm": np.zeros(3),
                "force_kg": np.zeros(3),
            },
        )
        command = {"position_counts": np.full(4, 200.0 * k), "max_velocity_counts_s": 1e4, "phase": 0}
        writer.append("command", t + 0.001, command)
    if status is None:
        writer.flush()
    else:
        writer.close(status)
    return path


def rewrite_info(run: Path, change) -> None:
    info = json.loads((run / "run.json").read_text())
    change(info)
    (run / "run.json").write_text(json.dumps(info))


def files_under(root: Path) -> set[Path]:
    return {p for p in root.rglob("*")}


# --- item 1: run.json's stream keys are checked where a run is read ---------------------------------

HOSTILE_KEYS = [
    "../../../../tmp/x",
    "../x",
    "..",
    ".",
    "",
    "/tmp/x",
    "a/b",
    "hand/../../x",
    "Hand",
    "hand\x00",
    "hand ",
    "ｈａｎｄ",  # full-width letters
    "x" * 300,
    "command",  # another stream's name: the key is not the spec's
]


@pytest.mark.parametrize("key", HOSTILE_KEYS)
def test_a_stream_key_that_is_not_its_checked_name_is_refused_by_the_reader(key: str, tmp_path: Path):
    run = write_run(tmp_path / "run")
    rewrite_info(run, lambda info: info["streams"].__setitem__(key, info["streams"].pop("hand")))
    with pytest.raises(RunFormatError, match=r"stream key|bad stream spec"):
        open_run(run)


def test_export_of_a_crafted_key_writes_nothing_anywhere(tmp_path: Path):
    run = write_run(tmp_path / "run")
    target = tmp_path / "victim"
    key = "../" * 12 + str(target).lstrip("/")
    rewrite_info(run, lambda info: info["streams"].__setitem__(key, info["streams"].pop("hand")))
    before = files_under(tmp_path)
    result = twin("export", str(run), "--format", "parquet", "--out", "ds", cwd=tmp_path)
    assert "stream key" in one_line(result)
    assert files_under(tmp_path) == before and not Path(f"{target}.parquet").exists()


@pytest.mark.parametrize("name", ["run.json"])
def test_run_json_nested_100000_deep_is_one_line(name: str, tmp_path: Path):
    run = write_run(tmp_path / "run")
    (run / name).write_text("[" * 100_000 + "]" * 100_000)
    for command in (["info", str(run)], ["export", str(run), "--out", "ds"]):
        assert "nested too deeply" in one_line(twin(*command, cwd=tmp_path))
    assert not (tmp_path / "ds").exists()


# --- item 2: twin view's blueprint in a private temporary directory ---------------------------------


def test_view_never_follows_a_planted_blueprint_path(tmp_path: Path):
    """The old predictable /tmp/twin-view-<name>.rbl, planted as a symlink: the file it points to stays
    as it was, and two runs of one name get two blueprints in private (0700) directories."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp / "twin-view-run.rbl").symlink_to(victim)
    shown = []
    for parent in ("a", "b"):
        run = write_run(tmp_path / parent / "run")
        (run / "run.rrd").write_bytes(b"")  # not a recording: the blueprint must not be written either
        result = twin("view", str(run), cwd=tmp_path, env={"TMPDIR": str(tmp)})
        assert "cannot read" in one_line(result)
    assert victim.read_text() == "precious"
    # a real recording: the blueprint is written, each in its own private directory
    from twin.api import compress, sim_backend

    for parent in ("a", "b"):
        run = tmp_path / parent / "real"
        compress(sim_backend(None), duration_s=0.2, out=run)
        result = twin("view", str(run), cwd=tmp_path, env={"TMPDIR": str(tmp)})
        assert result.returncode == 0, result.stderr
        (rbl,) = [w for w in result.stdout.split() if w.endswith(".rbl")]
        shown.append(Path(rbl))
    assert victim.read_text() == "precious"
    assert shown[0] != shown[1] and all(p.is_file() and p.parent.parent == tmp for p in shown)
    assert all(p.parent.stat().st_mode & 0o077 == 0 for p in shown)  # private to the user


# --- item 3: rig.toml calibration paths ---------------------------------------------------------------

RIG_PATHS = [
    ("tactile_table", "../../../../etc/passwd", "outside the rig file's directory"),
    ("tactile_table", "/etc/passwd", "outside the rig file's directory"),
    ("tactile_points", "../secret.csv", "outside the rig file's directory"),
    ("tactile_table", "link.csv", "outside the rig file's directory"),  # a symlink out
    ("tactile_table", "loop.csv", "outside the rig file's directory"),  # a symlink loop
    ("tactile_table", "", "is not a file name"),
    ("tactile_table", "sub", "no such file"),  # a directory
    ("tactile_table", "nope.csv", "no such file"),
    ("tactile_table", "garbage.csv", "garbage.csv:1: expected the header"),
    ("tactile_points", "garbage.csv", "garbage.csv:1: expected the header"),
    ("tactile_table", "binary.csv", "garbage"),
]


@pytest.mark.parametrize(("key", "name", "message"), RIG_PATHS)
def test_rig_calibration_paths_are_checked_and_parsed_without_a_tactile_section(
    key: str, name: str, message: str, tmp_path: Path
):
    lab = tmp_path / "lab"
    (lab / "sub").mkdir(parents=True)
    (tmp_path / "secret.csv").write_text("taxel,pressure_kpa,count\n")
    (lab / "link.csv").symlink_to(tmp_path / "secret.csv")
    (lab / "loop.csv").symlink_to(lab / "loop.csv")
    (lab / "garbage.csv").write_text("root:x:0:0:root:/root:/bin/bash\n")
    (lab / "binary.csv").write_bytes(b"\xff\xfe\x00garbage")
    (lab / "rig.toml").write_text(f'[hand]\nport = "loop://"\n[calibration]\n{key} = "{name}"\n')
    result = twin("run", "compress", "--backend", "hardware", "--rig", str(lab / "rig.toml"), "--out", "r",
                  cwd=tmp_path)  # fmt: skip
    line = one_line(result)
    assert message in line or (message == "garbage" and "binary.csv" in line), line
    assert not (tmp_path / "r").exists()


# --- item 4: exports that lie ---------------------------------------------------------------------------


def test_export_refuses_a_run_that_did_not_complete_unless_asked_and_records_its_status(tmp_path: Path):
    write_run(tmp_path / "done")
    write_run(tmp_path / "open", status=None)
    write_run(tmp_path / "failed", status="failed")
    for run in ("open", "failed"):
        line = one_line(twin("export", "done", run, "--out", "ds", cwd=tmp_path))
        assert "not 'complete'" in line and "--include-incomplete" in line
        assert not (tmp_path / "ds").exists()
    result = twin("export", "done", "open", "--include-incomplete", "--out", "ds", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    import pyarrow.parquet as pq

    episodes = pq.read_table(tmp_path / "ds/meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["source_status"] for e in episodes] == ["complete", "running"]


def test_export_refuses_the_same_run_twice(tmp_path: Path):
    write_run(tmp_path / "run")
    (tmp_path / "copy").mkdir()
    for f in (tmp_path / "run").rglob("*"):  # a copy of the directory is the same run (its run_id)
        target = tmp_path / "copy" / f.relative_to(tmp_path / "run")
        target.mkdir(exist_ok=True) if f.is_dir() else target.write_bytes(f.read_bytes())
    for second in ("run", "./run/", "copy"):
        line = one_line(twin("export", "run", second, "--out", "ds", cwd=tmp_path))
        assert "the same run as run" in line
    assert not (tmp_path / "ds").exists()


FORMATS = {"lerobot": {"meta", "data"}, "parquet": {"hand.parquet", "command.parquet", "runs.json"}}


def test_concurrent_exports_into_one_out_one_wins_and_the_other_says_so(tmp_path: Path):
    runs = [write_run(tmp_path / f"r{k}", samples=60) for k in range(3)]
    for attempt in range(3):
        out = tmp_path / f"ds{attempt}"
        argv = [[*TWIN, "export", *map(str, runs), "--format", fmt, "--out", str(out)] for fmt in FORMATS]
        procs = [subprocess.Popen(a, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for a in argv]
        results = [(*p.communicate(timeout=120), p.returncode) for p in procs]
        codes = sorted(code for _, _, code in results)
        assert codes == [0, 2], results
        (loser,) = [err for _, err, code in results if code == 2]
        assert loser.count("\n") == 1 and "twin: error:" in loser and "Traceback" not in loser
        winner = "lerobot" if results[0][2] == 0 else "parquet"
        assert {p.name for p in out.iterdir()} == FORMATS[winner]
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]


def test_info_says_when_a_running_runs_writer_is_gone(tmp_path: Path):
    code = "import sys; from twin.recording import RunWriter; RunWriter(sys.argv[1], {}).flush()"
    subprocess.run([sys.executable, "-c", code, str(tmp_path / "dead")], check=True)  # never closed
    info = json.loads(twin("info", "dead", "--json", cwd=tmp_path).stdout)
    assert info["status"] == "running" and info["writer_alive"] is False
    assert "its writer is gone" in twin("info", "dead", cwd=tmp_path).stdout
    writer = RunWriter(tmp_path / "alive", {})  # this process, still writing
    try:
        info = json.loads(twin("info", "alive", "--json", cwd=tmp_path).stdout)
        assert info["status"] == "running" and info["writer_alive"] is True
    finally:
        writer.close()
    assert json.loads(twin("info", "alive", "--json", cwd=tmp_path).stdout)["writer_alive"] is None


# --- item 8: one line for every OS error -----------------------------------------------------------------


def test_a_name_too_long_is_one_line(tmp_path: Path):
    write_run(tmp_path / "run")
    long = "x" * 300
    for command in (["export", "run", "--out", long], ["run", "compress", "--duration", "1", "--out", long]):
        line = one_line(twin(*command, cwd=tmp_path))
        assert "name too long" in line.lower(), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_emulate_rig_refuses_a_port_whose_neighbours_do_not_exist(tmp_path: Path):
    for port in ("tcp:65534", "tcp:65535"):  # the pads take PORT+1, the cameras PORT+2
        line = one_line(twin("emulate", "rig", "--port", port, "--duration", "1", cwd=tmp_path))
        assert "at most tcp:65533" in line
    assert list(tmp_path.iterdir()) == []


def test_a_parquet_export_of_a_run_with_no_command_samples(tmp_path: Path):
    write_run(tmp_path / "run", samples=0)
    result = twin("export", "run", "--format", "parquet", "--out", "ds", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    import pyarrow.parquet as pq

    assert pq.read_table(tmp_path / "ds" / "command.parquet").num_rows == 0


def test_output_that_cannot_be_written_is_one_line(tmp_path: Path):
    for redirect in ("> /dev/full", ">&-"):
        result = subprocess.run(f"{sys.executable} -m twin.cli objects --json {redirect}", shell=True,
                                capture_output=True, text=True, timeout=60)  # fmt: skip
        assert "<stdout>" in one_line(result)
