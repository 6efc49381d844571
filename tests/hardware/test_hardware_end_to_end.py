"""One flag: `twin run compress --backend hardware` against `twin emulate rig` on one machine writes
the same streams and units as the sim backend, and the fingers move the same way."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from twin.hardware.bh262.emulator import make_hand_emulator

from twin.compare import contact_windows_s, position_agreement, stream_mismatches
from twin.recording import open_run

TWIN = [sys.executable, "-m", "twin.cli"]


def twin(*args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([*TWIN, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def emulated_rig(tmp_path: Path):
    """`twin emulate rig` on a pty (hand and pads: this compares their tracking), with its rig.toml."""
    yield from _emulate_rig(tmp_path, "--no-cameras")


@pytest.fixture
def emulated_rig_with_cameras(tmp_path: Path):
    """`twin emulate rig` with the stereo pair streaming the twin's frames too."""
    yield from _emulate_rig(tmp_path)


def _emulate_rig(tmp_path: Path, *extra: str):
    """The emulator's output goes to a file (nothing blocks on a full pipe) and is printed at teardown:
    pytest shows it with a failing test, so a port lost mid-run says what the emulator saw."""
    rig_file, log = tmp_path / "rig.toml", tmp_path / "emulator.log"
    with log.open("w") as out:
        argv = ["emulate", "rig", "--port", "pty", "--rig-file", str(rig_file), "--duration", "120", *extra]
        proc = subprocess.Popen(
            [*TWIN, *argv],
            stdout=out,
            stderr=subprocess.STDOUT,
            text=True,
        )
    deadline = time.monotonic() + 120
    while "hand: /dev/" not in log.read_text() or "\nready" not in log.read_text():
        assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.1)
    assert "\ntactile: /dev/" in log.read_text(), log.read_text()
    try:
        yield rig_file
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        # the emulated hand now opens in the twin's own motion time, which a loaded suite slows
        proc.wait(timeout=60)
        print(f"--- twin emulate rig ({log}):\n{log.read_text()}")


@pytest.mark.slow
def test_hardware_run_with_cameras_reconstructs_the_emulated_foam(emulated_rig_with_cameras: Path, tmp_path):
    """The whole rig against emulators: hand, pads and the cameras' MJPEG streams, one flag."""
    hw = twin(
        "run", "compress", "--backend", "hardware", "--rig", str(emulated_rig_with_cameras),
        "--cameras", "--duration", "3", "--out", "hw", "--no-progress", cwd=tmp_path,
    )  # fmt: skip
    assert hw.returncode == 0, hw.stderr
    run = open_run(tmp_path / "hw")
    stereo = run.stream("stereo")
    assert len(stereo) == 91  # every pair scheduled on the run clock, recorded (late on a loaded host)
    assert (tmp_path / "hw" / "calibration" / "stereo_calibration.json").is_file()
    vision = [len(p) for p in stereo["points_m"]]
    # the tracker found the foam in every emulated frame (rig.toml's bbox); how much of it a frame shows
    # depends on where a late loop caught the fingers (one frame had 48 points on a loaded host)
    assert min(vision) > 0 and np.median(vision) > 100
    lo = np.percentile(stereo["points_m"][0], 25, axis=0)
    hi = np.percentile(stereo["points_m"][0], 75, axis=0)
    assert (lo > [-0.045, -0.045, 0.07]).all() and (hi < [0.045, 0.045, 0.16]).all()


@pytest.fixture
def emulated_rig_with_two_pairs(tmp_path: Path):
    """`twin emulate rig` with two opposite stereo pairs at 10 fps (four rendered cameras on 2 cores)."""
    yield from _emulate_rig(tmp_path, "--camera-placement", "lateral,opposite", "--camera-rate", "10")


@pytest.mark.slow
def test_two_opposite_pairs_through_the_bridge_are_recorded_and_read_as_the_twins_own(
    emulated_rig_with_two_pairs: Path, tmp_path: Path
):
    """Two [[stereo]] pairs in rig.toml: the run records `stereo` and `stereo_opposite`, each with its
    calibration, points and name, found as the two opposite pairs `twin identify --poisson-from-cameras`
    reads the bulge from; at rest they see the block's width as the twin's own two pairs do."""
    from twin.sim.foam import get_object
    from twin.sim.poisson import PALM_SURFACE_Z_M, observe
    from twin.vision import lateral_strain
    from twin.vision.fusion import VISION
    from twin.vision.strain_record import opposite_pair_streams

    hw = twin(
        "run", "compress", "--backend", "hardware", "--rig", str(emulated_rig_with_two_pairs),
        "--cameras", "--duration", "4", "--out", "hw", "--no-progress", cwd=tmp_path,
    )  # fmt: skip
    assert hw.returncode == 0, hw.stderr
    run = open_run(tmp_path / "hw")
    assert run.metadata["stereo_placements"] == ["lateral", "opposite"]
    assert opposite_pair_streams(run) == ("stereo", "stereo_opposite")
    for name in ("stereo_calibration.json", "stereo_calibration_opposite.json"):
        assert (tmp_path / "hw" / "calibration" / name).is_file()
    for stream in ("stereo", "stereo_opposite"):  # 10 fps, each pair on its own
        points = [len(p) for p in run.stream(stream)["points_m"]]
        assert len(points) >= 35 and np.median(points) > 100, (stream, len(points), np.median(points))

    def at_rest(stream: str) -> np.ndarray:
        first = run.stream(stream)
        return np.asarray(first["points_m"][0][first["point_source"][0] == VISION], dtype=float)

    block = get_object("block")
    width_m = lateral_strain.width_m(
        at_rest("stereo"), at_rest("stereo_opposite"), PALM_SURFACE_Z_M, block.size_m[2]
    )
    # The squeeze's bulge at the troughs is read the same way, from each pair's frame nearest each trough
    # (on hardware the pairs' frames arrive ms apart). How well it reads follows the host's load: on a quiet
    # machine eps_x 0.041 / eps_z -0.121 against the twin's 0.039 / -0.122, beside other tests stale
    # frames (the MJPEG sockets queue them) gave 0.13-0.48 or no frame near a trough: that is measured by
    # benchmarks/identification_hardware.py on a quiet machine, not asserted here.
    assert width_m == pytest.approx(observe(block, seed=0).width0_m, abs=0.002)


@pytest.mark.slow
def test_hardware_run_matches_the_sim_run(emulated_rig: Path, tmp_path: Path):
    sim = twin("run", "compress", "--duration", "10", "--out", "sim", "--no-progress", cwd=tmp_path)
    assert sim.returncode == 0, sim.stderr
    hw = twin(
        "run", "compress", "--backend", "hardware", "--rig", str(emulated_rig), "--duration", "10",
        "--out", "hw", "--no-progress", cwd=tmp_path,
    )  # fmt: skip
    assert hw.returncode == 0, hw.stderr
    run = open_run(tmp_path / "hw")
    assert run.status == "complete" and run.metadata["backend"] == "hardware"
    assert run.metadata["hand_driver"]["baud"] == 38400
    assert len(run.stream("hand").t_s) == 301
    # One clock: each command answers the reading just before it, before the next is taken (a late
    # loop once read on ahead and sent its commands seconds behind the hand stream; issue 37).
    hand_t, command_t = run.stream("hand").t_s, run.stream("command").t_s
    assert len(command_t) == len(hand_t)
    assert np.all(hand_t <= command_t) and np.all(command_t[:-1] < hand_t[1:])
    tactile = run.stream("tactile")  # the PPS driver against the rig emulator's pads, on the same twin
    # Every frame recorded once and in order, and every one missing counted: what the driver answers
    # for. Whether frames go missing, and the rate they arrive at, is the scheduler's: a host not
    # scheduled for ~0.4 s fills the pty's 4 KB buffer and the pads' later frames are lost, as on a real
    # line (seen beside a CPU hog: 23 frames, and 28.7 Hz; 24.8 Hz in a loaded suite).
    sequence = np.asarray(tactile["sequence"])
    assert np.all(np.diff(sequence) >= 1)
    dropped = np.asarray(tactile["dropped_frames"])
    assert dropped[-1] - dropped[0] == np.sum(np.diff(sequence) - 1)
    assert tactile.t_s[0] < 1.0 and tactile.t_s[-1] > 9.0  # the pads streamed through the whole run
    assert (tmp_path / "hw" / run.metadata["calibration_files"]["tactile_table"]).is_file()
    assert stream_mismatches(tmp_path / "sim", tmp_path / "hw") == []
    report = json.loads(twin("compare", "sim", "hw", "--json", cwd=tmp_path).stdout)
    assert report["mismatches"] == []
    # Where the host stalled the loop by over two periods the real-time grasp is that stalled loop's, not
    # the sim's (seen in 1 of 13 runs beside three CPU hogs, and in a suite beside two: a 117 ms stall at
    # 8.45 s, and the thumb lost the block). Then the run must say so, in run.json (issue 37: a test
    # asserts what the code answers for, not what a loaded host achieves); else the physics must agree.
    lag = run.metadata["hand_loop"]
    if lag["longest_behind_ms"] > 2 * lag["period_ms"]:
        assert lag["times_behind"] == len(lag["behind_from_s"]) >= 1
        assert "behind its schedule" in " ".join(twin("info", "hw", cwd=tmp_path).stdout.split())
        return
    sim_tips = open_run(tmp_path / "sim").stream("tactile").fields["pad_force_n"][-90:, :3].mean(axis=0)
    hw_tips = tactile.fields["pad_force_n"][-90:, :3].mean(axis=0)
    # The same squeeze felt by the same pads; a real-time grasp may settle a little differently.
    assert np.all(hw_tips > 0.5) and hw_tips.sum() == pytest.approx(sim_tips.sum(), rel=0.25)
    agreement = position_agreement(tmp_path / "sim", tmp_path / "hw")
    # Within 2 % of the travel everywhere but during the grasp (first contact to the compression),
    # where one 33 ms sample of timing jitter at 12000 counts/s is 400 counts (3.2 %) by itself and a
    # finger knocked off the block re-closes a sample sooner or later; there, and overall, the RMS says it.
    settled = position_agreement(
        tmp_path / "sim", tmp_path / "hw", exclude_s=contact_windows_s(tmp_path / "sim")
    )
    # A broken bridge (a unit, a sign, commands lost or applied late by the emulator) is tens of
    # percent of the travel. The host's scheduling is a few: outside the grasp the worst sample was
    # 3.6 % (F3) and the RMS 0.9 % beside a CPU hog and a second suite; 0.03-0.6 % RMS when less loaded.
    # How closely the fingers follow when the host keeps up is benchmarks/camera_bridge.py's figure.
    assert settled.max_relative_error < 0.08, settled
    assert np.all(settled.rms_error_counts / settled.travel_counts < 0.03), settled
    assert np.all(agreement.rms_error_counts / agreement.travel_counts < 0.04), agreement
    assert abs(agreement.lag_s) < 0.3
    assert report["max_relative_error_outside_contact"] == pytest.approx(settled.max_relative_error)


@pytest.mark.slow
def test_hand_flag_and_ctrl_c_idle_the_hand_and_keep_the_recording(tmp_path: Path):
    with make_hand_emulator("block") as emulator:
        pty = emulator.serve_pty()
        proc = subprocess.Popen(
            [*TWIN, "run", "compress", "--backend", "hardware", "--hand", pty, "--duration", "30",
             "--out", "hw", "--no-progress"],
            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        # Ctrl-C once 60 samples are on disk (a late loop sends more control blocks than it records
        # samples, so the emulator's count of them is no measure of what was recorded).
        recorded = _wait_for_samples(tmp_path / "hw", 60)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 130, err
        assert "interrupted" in err and "Traceback" not in err
        assert emulator.firmware.loop is None and emulator.firmware.baud == 9600
        assert "T" in emulator.firmware.commands[-4:]  # idled, then the rate restored
    run = open_run(tmp_path / "hw")
    assert run.status == "interrupted"
    samples = len(run.stream("hand").t_s)
    assert samples >= recorded >= 60  # what was on disk before Ctrl-C is still there after it
    # The 3-D view shows the hand as its readings pose it (hardware has no simulated scene): the
    # model's links logged over the run, the closing finger's distal link moving with the encoders.
    from twin.viz.rerun_log import read_rrd_entities, read_rrd_transforms

    rrd = tmp_path / "hw" / "run.rrd"
    assert read_rrd_entities(rrd).get("/world/bodies/f1_outer", 0) >= 10
    path = np.array([pose[:3, 3] for pose in read_rrd_transforms(rrd, "/world/bodies/f1_outer")])
    assert np.ptp(path, axis=0).max() > 0.01  # metres: it closed on the block


def _wait_for_samples(run_dir: Path, n: int, timeout_s: float = 60) -> int:
    """Until a running run has `n` hand samples on disk (a hang guard); how many it had."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            have = len(open_run(run_dir).stream("hand").t_s)
        except (OSError, ValueError, KeyError):  # not written yet, or between two writes
            have = 0
        if have >= n:
            return have
        time.sleep(0.1)
    raise AssertionError(f"{run_dir} got fewer than {n} hand samples within {timeout_s:g} s")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--backend", "hardware"], "no BH8 hand is configured"),
        (["--backend", "hardware", "--hand", "/dev/does-not-exist"], "cannot open the hand's port"),
        (["--hand", "/dev/ttyUSB0"], "--hand and --rig need --backend hardware"),
        (["--backend", "hardware", "--rig", "missing.toml"], "no such file"),
    ],
)
def test_bad_hardware_input_one_line_nothing_written(args, message, tmp_path: Path):
    result = twin("run", "compress", *args, "--out", "run", cwd=tmp_path, timeout=60)
    assert result.returncode != 0
    assert message in result.stderr and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_bad_rig_files_are_refused_in_one_line(tmp_path: Path):
    cases = {
        "[hand]\nport = 5\n": "[hand].port: expected str",
        "[hand]\nport = 'x'\nbaud = 12345\n": "baud 12345 not one of",
        "[hnad]\nport = 'x'\n": "unknown table(s) hnad",
        "[limits]\nfinger_counts = [100, 50]\n": "low < high",
        "[limits]\nmax_velocity_counts_s = -1\n": "must be a finite number > 0",
        "[hand\n": "not valid TOML",
        "[tactile]\nport = 'x'\n": "[tactile] pads need their calibration",
        "[calibration]\ntactile_tabel = 'a.csv'\n": "unknown file name(s) tactile_tabel",
        "[calibration]\ntactile_table = 'nope.csv'\n": "no such file",
        "[tactile]\nbaud = 9600\n": "[tactile] settings given without a port",
    }
    for text, message in cases.items():
        path = tmp_path / "rig.toml"
        path.write_text(text)
        result = twin(
            "run", "compress", "--backend", "hardware", "--rig", str(path), "--out", "r", cwd=tmp_path
        )
        assert result.returncode == 2, (text, result.stderr)
        assert message in result.stderr and "Traceback" not in result.stderr, (text, result.stderr)
        assert not (tmp_path / "r").exists()


def test_emulate_refuses_bad_options_in_one_line(tmp_path: Path):
    for args, message in [
        (["--baud", "1234"], "--baud 1234"),
        (["--port", "serial"], "expected pty or tcp:PORT"),
        (["--faults", "boom@3"], "--faults: bad item"),
        (["--object", "teapot"], "teapot"),
    ]:
        result = twin("emulate", "hand", *args, "--duration", "1", cwd=tmp_path, timeout=60)
        assert result.returncode == 2 and message in result.stderr, (args, result.stderr)
        assert "Traceback" not in result.stderr


def test_emulator_serves_tcp_and_exits_after_its_duration(tmp_path: Path):
    t0 = time.monotonic()
    result = twin("emulate", "hand", "--port", "tcp:0", "--object", "none", "--duration", "1", cwd=tmp_path)
    assert result.returncode == 0
    assert "hand: socket://127.0.0.1:" in result.stdout and "emulator stopped" in result.stdout
    assert time.monotonic() - t0 < 30


def test_the_rig_going_away_mid_run_is_one_clear_error_and_the_run_is_kept(tmp_path: Path):
    """`twin emulate rig` stops (Ctrl-C) under a 30 s run once a second of it is on disk, and every port
    vanishes at once: one error line, no traceback, exit 2, and the samples before it are in a run
    marked failed. (Stopping it by its own --duration raced a slow start on a busy machine.)"""
    emulator = _emulate_rig(tmp_path, "--no-cameras")
    rig_file = next(emulator)
    proc = subprocess.Popen(
        [*TWIN, "run", "compress", "--backend", "hardware", "--rig", str(rig_file), "--duration", "30",
         "--out", "hw", "--no-progress"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        recorded = _wait_for_samples(tmp_path / "hw", 30)
    finally:
        emulator.close()  # SIGINT: the emulator stops and its ports go away
        _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 2, stderr
    assert "Traceback" not in stderr
    errors = [line for line in stderr.splitlines() if line.startswith("twin: error:")]
    assert len(errors) == 1, stderr
    run = open_run(tmp_path / "hw")
    assert run.status == "failed" and not run.truncated
    assert len(run.stream("hand")) >= recorded  # every sample on disk before the rig went away


def _wait_for_a_record_batch(stream: Path, timeout_s: float = 60) -> None:
    """Until `stream` has grown past its first write (its schema): samples are on disk (a hang guard)."""
    deadline = time.monotonic() + timeout_s
    first = 0
    while time.monotonic() < deadline:
        size = stream.stat().st_size if stream.exists() else 0
        if first and size > first:
            return
        first = first or size
        time.sleep(0.05)
    raise AssertionError(f"{stream} got no samples within {timeout_s:g} s")


def test_a_killed_emulator_is_a_lost_port_not_a_watchdog_stop(tmp_path: Path):
    """SIGKILL on `twin emulate hand` mid-run: the pty goes away (EOF/EIO). The error says the port was
    lost (not that feedback stopped) and does not claim the hand was idled: nothing acknowledged T."""
    rig_file = tmp_path / "rig.toml"
    emulator = subprocess.Popen(
        [*TWIN, "emulate", "hand", "--port", "pty", "--rig-file", str(rig_file), "--duration", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    run_proc = None
    try:
        assert any(line.startswith("ready") for line in emulator.stdout)
        run_proc = subprocess.Popen(
            [*TWIN, "run", "compress", "--backend", "hardware", "--rig", str(rig_file), "--duration", "30",
             "--out", "hw", "--no-progress"],
            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        _wait_for_a_record_batch(tmp_path / "hw" / "streams" / "hand.arrows")
        emulator.kill()
        _, err = run_proc.communicate(timeout=60)
    finally:
        for proc in (emulator, run_proc):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    assert run_proc.returncode == 2, err
    errors = [line for line in err.splitlines() if line.startswith("twin: error:")]
    assert len(errors) == 1 and "Traceback" not in err, err
    reason = errors[0].split(";")[0]
    assert "the hand's port /dev/pts/" in reason and "was lost" in reason, err
    assert "no valid feedback" not in errors[0] and "motors terminated" not in errors[0]
    assert "the hand was idled" not in errors[0]
    run = open_run(tmp_path / "hw")
    assert run.status == "failed" and "was lost" in run.info["error"]
    assert len(run.stream("hand")) > 0
