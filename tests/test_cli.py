"""The `twin` CLI end to end: real runs on disk, read back with the reader and Rerun's own API,
and bad input that ends in one line, a non-zero exit and nothing written."""

import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from twin.cli import main
from twin.recording import open_run
from twin.sim.foam import LIBRARY

TWIN = [sys.executable, "-m", "twin.cli"]


def twin(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    env.pop("DISPLAY", None)
    return subprocess.run([*TWIN, *args], capture_output=True, text=True, env=env, timeout=600)


def test_objects_json_lists_the_library():
    result = twin("objects", "--json")
    assert result.returncode == 0, result.stderr
    objects = json.loads(result.stdout)
    assert {o["name"] for o in objects} == set(LIBRARY)
    assert {o["shape"] for o in objects} >= {"block", "cylinder", "sphere"}
    assert {o["stiffness_class"] for o in objects} >= {"soft", "medium", "firm"}
    assert all(o["young_pa"] > 0 and 0 <= o["poisson"] < 0.5 for o in objects)


@pytest.mark.slow
def test_run_compress_end_to_end_then_info_and_rrd(tmp_path: Path):
    out = tmp_path / "run"
    result = twin(
        "run", "compress", "--object", "soft_block", "--duration", "3", "--seed", "4",
        "--young", "20e3", "--out", str(out), "--no-progress",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    info = json.loads(twin("info", str(out), "--json").stdout)
    assert info["status"] == "complete"
    streams = {s["name"]: s for s in info["streams"]}
    hand = streams["hand"]
    assert hand["rate_hz"] == 30 and hand["measured_rate_hz"] == pytest.approx(30, rel=0.01)
    assert hand["samples"] == 91
    assert {f["kind"] for f in hand["fields"].values()} == {"raw", "physical"}
    assert hand["fields"]["strain_counts"]["unit"] == "counts"
    assert hand["fields"]["torque_nm"]["unit"] == "N*m"
    meta = info["metadata"]
    assert meta["object"]["young_pa"] == 20e3 and meta["seed"] == 4
    assert meta["calibration"]["strain_torque_eq2"]["slope_nm"] == 0.0085
    assert "--young" in meta["command_line"]
    # the squeeze the procedure chose and the readings at the force cap, as run.json has them
    text = " ".join(twin("info", str(out)).stdout.split())  # rich wraps at the terminal's width
    amplitude = meta["squeeze_amplitude"]["amplitude_counts"]
    assert f"squeeze: {amplitude:.0f} counts" in text
    counts = ", ".join(f"F{k + 1} {n}" for k, n in enumerate(meta["force_cap"]["readings_at_cap"]))
    assert f"readings at the 2 kg fingertip-force cap: {counts}" in text
    # The .rrd reads back with Rerun's own API: the plotted positions are the recorded ones.
    from twin.viz.rerun_log import read_rrd_entities, read_rrd_scalars

    entities = read_rrd_entities(out / "run.rrd")
    assert any("flex" in e for e in entities)
    times, values = read_rrd_scalars(out / "run.rrd", "/plots/hand/position_counts")
    recorded = open_run(out).stream("hand")
    assert len(times) == len(recorded)
    assert np.allclose(values, recorded["position_counts"][:, :3])


def test_python_dash_m_twin_is_the_twin_command():
    """`python -m twin` (what a user tries first) runs the same command as `python -m twin.cli`."""
    argv = [sys.executable, "-m", "twin", "objects", "--json"]
    result = subprocess.run(argv, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == json.loads(twin("objects", "--json").stdout)


@pytest.mark.slow
@pytest.mark.parametrize("fidelity", ["fast", "faithful"])
@pytest.mark.parametrize("name", sorted(LIBRARY))
def test_every_library_foam_runs_10_s_headless(name: str, fidelity: str, tmp_path: Path, caplog):
    """A whole compress run of every library foam at both fidelities: zero MuJoCo warnings (the counters and
    MuJoCo's log), and the grasp holds to the end."""
    out = tmp_path / name
    argv = ["run", "compress", "--object", name, "--fidelity", fidelity, "--duration", "10"]
    with caplog.at_level(logging.WARNING, logger="absl"):
        assert main([*argv, "--out", str(out), "--no-progress"]) == 0
    assert not [r.getMessage() for r in caplog.records if r.name == "absl"]
    run = open_run(out)
    assert run.status == "complete"
    assert run.metadata["object"]["fidelity"] == fidelity
    assert run.metadata["mujoco_warnings"] == {}
    assert run.metadata["final_phase"] == "compress"
    # run.json says where the safety layer's 2 kg cap shaped the curves: the readings at it per finger
    cap = run.metadata["force_cap"]
    at_cap = run.stream("hand")["force_kg"][:, :3] >= cap["limit_kg"]
    assert cap["readings_at_cap"] == at_cap.sum(axis=0).tolist()
    assert cap["times_reached"] == (at_cap[0] + (at_cap[1:] & ~at_cap[:-1]).sum(axis=0)).tolist()
    torque = run.stream("hand")["torque_nm"]
    # Far above the 0.005 N*m gauge noise: every finger still squeezes the foam through most of each of
    # the last 2 s's cycles. (Most, not all: on the 150 kPa firm block under MuJoCo 4.0 the thumb unloads
    # to 0 N*m at the compression's peaks while F1 and F2 reach 0.9 N*m; 3.17's dipped to 0.12. Not yet
    # for the faithful soft foams, whose deeper dents outgrow the procedure's constants, tuned on the
    # trilinear foam: the re-baseline of issue 19.)
    if fidelity == "fast":
        assert (np.median(torque[-60:, :3], axis=0) > 0.05).all(), np.median(torque[-60:, :3], axis=0)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--object", "pillow"], "unknown object 'pillow'"),
        (["--young", "-5"], "argument --young: must be a finite number > 0"),
        (["--poisson", "0.5"], "argument --poisson: must be a finite number >= 0 and < 0.5"),
        (["--size-mm", "200", "200", "50"], "does not fit in the hand"),
        (["--duration", "0"], "argument --duration: must be a finite number >= 0.001"),
        (["--duration", "inf"], "--duration: must be a finite number >= 0.001 and <= 86400, got 'inf'"),
        (["--seed", "-1"], "argument --seed: must be an integer >= 0 and <= 4294967295, got '-1'"),
        (["--young", "1e308"], "argument --young: must be a finite number > 0 and <= 1e+09"),
        (["--backend", "hardware"], "no BH8 hand is configured"),
    ],
)
def test_bad_input_one_line_nonzero_nothing_written(args, message, tmp_path: Path):
    out = tmp_path / "run"
    result = twin("run", "compress", *args, "--out", str(out), "--no-progress")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twin: error:") and message in lines[0], result.stderr
    assert not out.exists()


def test_unwritable_or_used_out_is_refused_before_simulating(tmp_path: Path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    result = twin("run", "compress", "--out", str(blocker / "run"), "--no-progress")
    assert result.returncode == 2 and "is not a directory" in result.stderr
    used = tmp_path / "used"
    used.mkdir()
    (used / "keep.txt").write_text("precious")
    result = twin("run", "compress", "--out", str(used), "--no-progress")
    assert result.returncode == 2 and "not empty" in result.stderr
    assert sorted(p.name for p in used.iterdir()) == ["keep.txt"]


def test_ctrl_c_marks_the_run_interrupted_and_keeps_the_data(tmp_path: Path):
    out = tmp_path / "run"
    env = {**os.environ, "MUJOCO_GL": "egl"}
    cmd = [*TWIN, "run", "compress", "--duration", "120", "--out", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (out / "streams").exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr
    run = open_run(out)
    assert run.status == "interrupted"
    assert len(run.stream("hand")) > 10
    assert not run.truncated


def test_info_and_view_on_something_that_is_not_a_run(tmp_path: Path):
    result = twin("info", str(tmp_path))
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    result = twin("view", str(tmp_path))
    assert result.returncode == 2 and "no Rerun recording" in result.stderr


def test_sigkill_mid_run_loses_at_most_about_a_second(tmp_path: Path):
    out = tmp_path / "run"
    env = {**os.environ, "MUJOCO_GL": "egl"}
    cmd = [*TWIN, "run", "compress", "--duration", "300", "--out", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not (out / "streams" / "hand.arrows").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(3.0)
    killed_at = time.time()
    proc.kill()
    proc.wait(timeout=30)
    # Data reached the OS moments before the kill (the writer flushes every 0.25 s of run or wall time).
    assert killed_at - (out / "streams" / "hand.arrows").stat().st_mtime < 1.0
    run = open_run(out)
    assert run.status == "running"  # never closed: it does not claim to be complete
    hand = run.stream("hand")
    assert len(hand) > 30
    # Contiguous from t = 0: nothing before the cut is missing.
    assert hand.t_s[0] == 0.0
    assert np.diff(hand.t_s).max() < 2.5 / 30
    # Every stream reached about the same instant: at most ~1 s of run time was lost from any.
    ends = {name: run.stream(name).t_s[-1] for name in ("hand", "command", "truth")}
    assert max(ends.values()) - min(ends.values()) < 1.0


# --- issue 18: every failure ends in one true line --------------------------------------------------


def one_line(result: subprocess.CompletedProcess, *fragments: str) -> str:
    """The refusal's only stderr line (exit 2, no traceback), holding every fragment."""
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and lines[0].startswith("twin: error:"), result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    assert all(f in lines[0] for f in fragments), lines[0]
    return lines[0]


def in_process(capsys: pytest.CaptureFixture, *args: str) -> subprocess.CompletedProcess:
    """`twin ARGS` through main() in this process (no interpreter start-up or imports per case)."""
    capsys.readouterr()
    try:
        code = main(list(args))
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, out, err)


@pytest.fixture(scope="module")
def short_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3 s sim compress run (made once for the tests below, which only read it)."""
    out = tmp_path_factory.mktemp("short") / "run"
    assert main(["run", "compress", "--duration", "3", "--out", str(out), "--no-progress"]) == 0
    return out


def _copy_run(run: Path, to: Path, **metadata: object) -> Path:
    """A copy of a run with some metadata keys replaced (None: removed), as a hardware run lacks them;
    without the streams' digests (as a run written before they were), so its files may be cut."""
    import shutil

    shutil.copytree(run, to)
    info = json.loads((to / "run.json").read_text())
    info.pop("integrity", None)
    for key, value in metadata.items():
        if value is None:
            info["metadata"].pop(key, None)
        else:
            info["metadata"][key] = value
    (to / "run.json").write_text(json.dumps(info))
    return to


def test_fit_refuses_an_unknown_object_and_a_size_without_one(short_run: Path):
    one_line(twin("fit", str(short_run), "--object", "pillow"), "unknown object 'pillow'")
    one_line(twin("fit", str(short_run), "--size-mm", "60", "60", "70"), "--size-mm needs --object")
    one_line(twin("fit", str(short_run), "--young", "inf"), "argument --young", "got 'inf'")
    assert not (short_run / "fit").exists()


@pytest.mark.slow
def test_fit_takes_object_and_size_for_a_run_that_does_not_describe_its_object(short_run: Path, tmp_path):
    """A hardware run records no object: --object/--size-mm name it, and the replays start (the old
    code answered 'name it with --object' whatever was given). Stopped at the first replay."""
    import threading

    hardware_like = _copy_run(short_run, tmp_path / "hw", object=None, backend="hardware")
    env = {**os.environ, "MUJOCO_GL": "egl"}
    cmd = [*TWIN, "fit", str(hardware_like), "--object", "block", "--size-mm", "60", "60", "70"]
    proc = subprocess.Popen([*cmd, "--workers", "1"], env=env, stderr=subprocess.PIPE, text=True)
    seen: list[str] = []
    started = threading.Event()

    def read() -> None:
        while ch := proc.stderr.read(1):
            seen.append(ch)
            if "replays" in "".join(seen[-20:]):
                started.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        started.wait(timeout=120)  # hang guard: a replay takes a second or two
        exited_early = proc.poll()
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        reader.join(timeout=10)
    stderr = "".join(seen)
    assert exited_early is None and started.is_set(), stderr
    assert "--object" not in stderr and "does not describe its object" not in stderr


def test_identify_refuses_bad_sizes_and_a_compress_run_as_free(short_run: Path):
    for size in (["nan", "nan", "nan"], ["0", "0", "0"], ["60", "60", "inf"]):
        one_line(twin("identify", str(short_run), "--shape", "block", "--size-mm", *size), "--size-mm")
    one_line(
        twin("identify", str(short_run), "--free", str(short_run)), "a 'compress' run, not a `twin run free`"
    )
    assert not (short_run / "identify").exists()


def test_compare_with_a_run_of_fewer_than_two_samples_is_one_line(short_run: Path, tmp_path: Path):
    empty = _copy_run(short_run, tmp_path / "empty")
    (empty / "streams" / "hand.arrows").write_bytes(b"")  # a run that failed before its first sample
    one_line(twin("compare", str(short_run), str(empty)), "0 hand sample(s)", "at least two")
    one_line(twin("compare", str(empty), str(short_run)), "0 hand sample(s)")


def test_info_says_when_readable_samples_differ_from_run_json(short_run: Path, tmp_path: Path):
    cut = _copy_run(short_run, tmp_path / "cut")
    (cut / "streams" / "hand.arrows").write_bytes(b"")
    result = twin("info", str(cut))
    assert result.returncode == 0, result.stderr
    assert "hand: 0 samples readable, run.json records 91" in " ".join(result.stdout.split())
    info = json.loads(twin("info", str(cut), "--json").stdout)
    assert info["samples_differ"] == [{"stream": "hand", "readable": 0, "recorded": 91}]
    assert info["status"] == "complete"
    assert json.loads(twin("info", str(short_run), "--json").stdout)["samples_differ"] == []


@pytest.mark.parametrize(
    ("damage", "reason"),
    [
        ({"model.json": "[1, 2]"}, "holds list"),
        ({"model.json": "{}"}, "points must be an integer"),
        ({"model.json": '{"points": 8, "x_mean": '}, "JSONDecodeError"),
        ({"model.pt": b"\x00garbage" * 10}, "UnpicklingError"),
        ({"model.pt": b""}, "not a trained shape model"),
    ],
)
def test_a_corrupt_model_for_predict_is_one_line(damage: dict, reason: str, tmp_path: Path, capsys):
    from twin.shape.model import ShapeMLP, ShapeModel

    rng = np.random.default_rng(0)
    ShapeModel(
        net=ShapeMLP(8),
        x_mean=rng.normal(size=6),
        x_std=np.ones(6),
        y_mean=rng.normal(size=16),
        y_std=np.ones(16),
        metadata={"object": "block", "target": "hull"},
    ).save(tmp_path / "model")
    for name, content in damage.items():
        path = tmp_path / "model" / name
        path.write_bytes(content) if isinstance(content, bytes) else path.write_text(content)
    out = tmp_path / "run"
    model = str(tmp_path / "model")
    result = in_process(capsys, "run", "compress", "--predict", model, "--out", str(out), "--no-progress")
    one_line(result, "--predict", "not a trained shape model", reason)
    assert not out.exists()


@pytest.mark.parametrize(
    ("index", "reason"),
    [
        ("{}", "no 'trajectories' list"),
        ("garbage{", "not readable JSON"),
        ('{"trajectories": [5]}', "trajectories[0].object_name"),
        ('{"trajectories": [{"object_name": "block", "file": 3, "index": 0}]}', "trajectories[0].file"),
    ],
)
def test_a_garbage_sweep_index_for_train_is_one_line(index: str, reason: str, tmp_path: Path, capsys):
    (tmp_path / "index.json").write_text(index)
    one_line(in_process(capsys, "train", str(tmp_path), "--object", "block"), "index.json", reason)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["index.json"]


def test_calibrate_refuses_to_overwrite_without_force(tmp_path: Path):
    taken = tmp_path / "calibration.json"
    taken.write_text("precious")
    one_line(twin("calibrate", "cameras", "--out", str(taken)), "exists", "--force")
    one_line(twin("calibrate", "cameras", "--seed", "-1", "--out", str(tmp_path / "new.json")), "--seed")
    assert taken.read_text() == "precious" and sorted(p.name for p in tmp_path.iterdir()) == [taken.name]


def test_emulate_refuses_a_rig_file_under_a_file_before_serving(tmp_path: Path):
    (tmp_path / "plain").write_text("")
    result = twin(
        "emulate", "hand", "--rig-file", str(tmp_path / "plain" / "emu" / "rig.toml"), "--duration", "1"
    )
    one_line(result, "--rig-file", "is not a directory")
    assert "ready" not in result.stdout


def test_emulate_writes_its_rig_file_into_a_new_directory(tmp_path: Path):
    """docs/cli.md's `twin emulate rig --rig-file runs/emu/rig.toml`, from a fresh clone: runs/emu is made."""
    argv = ["emulate", "rig", "--rig-file", "runs/emu/rig.toml", "--no-cameras", "--duration", "0.5"]
    result = subprocess.run([*TWIN, *argv], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "rig file: runs/emu/rig.toml" in result.stdout
    assert '\n[hand]\nport = "/dev/' in (tmp_path / "runs" / "emu" / "rig.toml").read_text()
    assert (tmp_path / "runs" / "emu" / "calibration").is_dir()


@pytest.mark.parametrize(
    ("table", "key"),
    [
        ('port = "bh8emu://"\ntimeout_s = inf', "[hand].timeout_s"),
        ('port = "bh8emu://"\nbaud_switch_wait_s = -1.0', "[hand].baud_switch_wait_s"),
        ('port = "bh8emu://"\nbaud_switch_wait_s = nan', "[hand].baud_switch_wait_s"),
        ('port = "bh8emu://"\nrate_hz = -inf', "[hand].rate_hz"),
        ('port = "bh8emu://"\nwatchdog_cycles = 0', "[hand].watchdog_cycles"),
    ],
)
def test_rig_toml_numbers_are_checked_at_load(table: str, key: str, tmp_path: Path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_text(f"[hand]\n{table}\n")
    out = tmp_path / "run"
    argv = ["run", "compress", "--backend", "hardware", "--rig", str(rig), "--out", str(out)]
    line = one_line(in_process(capsys, *argv), f"{rig}: {key} must be", "got")
    assert line.count(str(rig)) == 1
    assert not out.exists()


def test_rig_messages_name_the_file_once(tmp_path: Path):
    rig = tmp_path / "noport.toml"
    rig.write_text("[hand]\nbaud = 9600\n")
    result = twin("run", "compress", "--backend", "hardware", "--rig", str(rig), "--no-progress")
    assert one_line(result, "[hand] settings given without a port").count("noport.toml") == 1


def test_a_hardware_run_that_recovered_cycles_says_so_in_one_warning_line(tmp_path: Path, capsys):
    # drop@31: the emulator swallows one reply; the driver re-enters RealTime mode and loses no sample.
    # The recovery is listed in run.json; the terminal gets one summary line, not the driver's log.
    out = tmp_path / "hw"
    argv = ["run", "compress", "--backend", "hardware", "--hand", "bh8emu://?faults=drop@31"]
    assert main([*argv, "--duration", "2", "--out", str(out), "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert "run complete" in captured.out
    recovered = open_run(out).metadata["hand_recoveries"]
    assert len(recovered) >= 1
    warnings = [line for line in captured.err.splitlines() if line.startswith("twin: warning:")]
    assert len(warnings) == 1 and f"recovered {len(recovered)} cycle(s)" in warnings[0], captured.err
    assert "hand feedback lost" not in captured.err


def test_a_bad_emulator_url_is_one_line_naming_the_url_once(tmp_path: Path, capsys):
    argv = ["run", "compress", "--backend", "hardware", "--hand", "bh8emu://?baud=fast"]
    assert main([*argv, "--duration", "2", "--out", str(tmp_path / "x"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.count("bh8emu://?baud=fast") == 1, err
    assert not (tmp_path / "x").exists()


def test_version_and_help_show_what_a_user_needs():
    from twin import __version__

    assert twin("--version").stdout.strip() == f"twin {__version__}"
    compress = " ".join(twin("run", "compress", "--help").stdout.split())
    assert "run length (s), up to a day (default: 10.0)" in compress
    assert "(default: block)" in compress and "(default: sim)" in compress
    assert "(default: 20.0)" in " ".join(twin("run", "free", "--help").stdout.split())


def test_objects_fits_80_columns_and_a_reader_that_leaves_early_is_no_error():
    env = {**os.environ, "COLUMNS": "80"}
    table = subprocess.run([*TWIN, "objects"], capture_output=True, text=True, env=env).stdout
    assert max(len(line.rstrip()) for line in table.splitlines()) <= 80
    for p in LIBRARY.values():  # every name and size whole, on its own line
        size = "x".join(f"{s * 1e3:.0f}" for s in p.size_m)
        assert any(line.split()[:1] == [p.name] and size in line for line in table.splitlines()), p.name
    read, write = os.pipe()
    os.close(read)  # `twin objects --json | head`: the reader is gone before the first write
    result = subprocess.run([*TWIN, "objects", "--json"], stdout=write, stderr=subprocess.PIPE, text=True)
    os.close(write)
    assert result.returncode == 0 and result.stderr == ""


def test_a_refusal_draws_no_progress_bar_first(tmp_path: Path):
    result = twin("run", "compress", "--backend", "hardware", "--out", str(tmp_path / "r"))  # progress on
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and "no BH8 hand is configured" in result.stderr


def test_view_without_a_display_prints_commands_that_run(tmp_path: Path):
    out = tmp_path / "run"
    assert main(["run", "compress", "--duration", "0.5", "--out", str(out), "--no-progress"]) == 0
    shown = twin("view", str(out)).stdout
    assert "FILES" not in shown and f"--serve-web {out / 'run.rrd'}" in shown
    assert "--web-viewer-port 9090 --port 9876" in shown  # the defaults, unless chosen:
    shown = twin("view", str(out), "--port", "19876", "--web-viewer-port", "19090").stdout
    assert "--web-viewer-port 19090 --port 19876" in shown and "-L 19090:localhost:19090" in shown
    assert "http://localhost:19090/?url=rerun%2Bhttp://localhost:19876/proxy" in shown


def test_emulate_rig_writes_nothing_into_the_working_directory(tmp_path: Path):
    argv = ["emulate", "rig", "--no-cameras", "--duration", "0.5"]
    result = subprocess.run([*TWIN, *argv], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 0, result.stderr
    line = next(line for line in result.stdout.splitlines() if line.startswith("rig file:"))
    rig_file = Path(line.split()[-1])
    assert not rig_file.is_relative_to(tmp_path) and list(tmp_path.iterdir()) == []
