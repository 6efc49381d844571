"""The rig on sim time: each stream at its declared rate, readings delivered after the declared
latency, commands recorded as applied, and identical recordings for identical seeds."""

import time

import numpy as np
import pytest
from twin.experiments.compress import PHASES, CompressController, run_compress
from twin.hardware.backend import HardwareBackend
from twin.hardware.bh262.emulator import make_hand_emulator
from twin.hardware.rig_config import RigConfig, load_rig

from twin.interface.devices import HandCommand, HandReading
from twin.interface.errors import ConfigError, DeviceError
from twin.interface.hand_spec import HandConfig
from twin.recording import RunWriter, open_run
from twin.rig import Rig
from twin.session import run_experiment
from twin.sim.backend import SimBackend
from twin.sim.foam import LIBRARY


class Recorder:
    """A controller that remembers when each reading arrived and holds the hand still."""

    phase = "close"

    def __init__(self, backend: SimBackend) -> None:
        self.backend = backend
        self.arrivals: list[tuple[float, float]] = []

    def __call__(self, reading: HandReading) -> HandCommand:
        self.arrivals.append((reading.t_s, self.backend.clock.now()))
        return HandCommand(np.array([3000.0, 3000.0, 3000.0, 0.0]), 5000)


@pytest.mark.parametrize(("rate_hz", "latency_s"), [(30.0, 0.004), (18.0, 0.02)])
def test_hand_sampled_at_its_rate_and_delivered_after_its_latency(rate_hz, latency_s):
    backend = SimBackend(None, HandConfig(rate_hz=rate_hz, latency_s=latency_s))
    backend.connect()
    controller = Recorder(backend)
    result = Rig(backend, phases=PHASES).run(controller, duration_s=2.0)
    sampled, arrived = np.array(controller.arrivals).T
    assert result.samples["hand"] == int(2.0 * rate_hz) + 1
    step = backend.world.timestep_s
    # Sample instants fall on the physics grid: each within one step of k / rate, the mean rate exact.
    assert sampled == pytest.approx(np.arange(len(sampled)) / rate_hz, abs=step + 1e-9)
    assert (len(sampled) - 1) / (sampled[-1] - sampled[0]) == pytest.approx(rate_hz, rel=0.01)
    assert arrived - sampled == pytest.approx(np.full(len(sampled), latency_s), abs=step / 2 + 1e-9)


def test_same_seed_same_recording_different_seed_different_noise(tmp_path):
    def record(seed: int, name: str):
        backend = SimBackend(LIBRARY["block"], seed=seed)
        backend.connect()
        with RunWriter(tmp_path / name, {"seed": seed}) as writer:
            Rig(backend, writer, phases=PHASES).run(CompressController(), duration_s=1.5)
        return open_run(tmp_path / name)

    a, b, c = record(5, "a"), record(5, "b"), record(6, "c")
    for stream in ("hand", "command", "truth"):
        for field in a.streams[stream].fields:
            assert np.array_equal(a.stream(stream)[field], b.stream(stream)[field]), (stream, field)
    assert not np.array_equal(a.stream("hand")["strain_counts"], c.stream("hand")["strain_counts"])


# --- what a stopped run says: the stop and whether the hand acknowledged its idle (issue 18) -------------


class Interrupting(CompressController):
    """The compress procedure, interrupted (as by Ctrl-C or SIGTERM) after `after_s` of run time."""

    def __init__(self, after_s: float) -> None:
        super().__init__()
        self.after_s = after_s

    def __call__(self, reading: HandReading) -> HandCommand:
        if reading.t_s >= self.after_s:
            raise KeyboardInterrupt
        return super().__call__(reading)


class Slow(CompressController):
    """The compress procedure taking 60 ms per reading: a 30 Hz loop cannot keep its rate."""

    def __call__(self, reading: HandReading) -> HandCommand:
        time.sleep(0.06)
        return super().__call__(reading)


def test_an_interrupted_run_says_so_and_that_the_hand_acknowledged_its_idle(tmp_path):
    backend = SimBackend(LIBRARY["block"], seed=0)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(
            backend=backend,
            controller=Interrupting(0.5),
            phases=PHASES,
            duration_s=2.0,
            run_dir=tmp_path / "run",
            experiment={"name": "compress"},
        )
    run = open_run(tmp_path / "run")
    assert run.status == "interrupted"
    assert run.info["error"] == "interrupted (Ctrl-C or SIGTERM); the hand was idled"
    assert run.metadata["stop"]["idle"] == "acknowledged"
    assert run.corrupt_streams() == {} and run.sample_mismatches() == {}


@pytest.mark.slow
def test_a_watchdog_stop_on_a_silent_hand_says_the_idle_failed(tmp_path):
    """The emulated hand stops answering for good (mute): the watchdog stops the run, the idle gets no
    answer either, and both run.json and the raised error say the hand may still be powered."""
    with make_hand_emulator("block", faults="mute@15") as emulator:
        backend = HardwareBackend(RigConfig().with_hand_port(emulator.serve_tcp()))
        with pytest.raises(DeviceError) as raised:
            run_compress(backend, tmp_path / "run", duration_s=10.0, object_name="block")
    message = str(raised.value)
    assert "idling the hand failed" in message and "may still be powered" in message
    assert len(message.splitlines()) == 1
    run = open_run(tmp_path / "run")
    assert run.status == "failed" and run.info["error"] == message
    assert run.metadata["stop"]["idle"] == "failed" and run.metadata["stop"]["error_type"] == "WatchdogError"


def test_a_garbage_tactile_table_is_refused_before_the_hand_is_touched(tmp_path):
    """rig.toml names a tactile table that is not one: one ConfigError when the rig file is read (with
    or without a [tactile] section), and the hand (an emulator listening) never received a byte."""
    (tmp_path / "table.csv").write_text("this is not,a calibration table\n1,2\n")
    with make_hand_emulator("block") as emulator:
        url = emulator.serve_tcp()
        for tactile in ('[tactile]\nport = "socket://127.0.0.1:9"\n', ""):
            (tmp_path / "rig.toml").write_text(
                f'[hand]\nport = "{url}"\n{tactile}[calibration]\ntactile_table = "table.csv"\n'
            )
            with pytest.raises(ConfigError) as raised:
                load_rig(tmp_path / "rig.toml")
            assert str(raised.value).startswith(f"{tmp_path / 'table.csv'}:1: ")  # the user's file
        assert emulator.firmware.commands == []


@pytest.mark.slow
def test_a_hardware_loop_that_misses_its_rate_says_so(tmp_path, capsys):
    """A procedure too slow for 30 Hz (60 ms a reading): the run completes, and run.json, the outcome
    and the reader carry one warning line with the rate the loop achieved."""
    with make_hand_emulator("block") as emulator:
        backend = HardwareBackend(RigConfig().with_hand_port(emulator.serve_tcp()))
        outcome = run_experiment(
            backend=backend,
            controller=Slow(),
            phases=PHASES,
            duration_s=1.0,
            run_dir=tmp_path / "run",
            experiment={"name": "compress"},
        )
    assert outcome.status == "complete"
    assert len(outcome.warnings) == 1 and outcome.warnings[0].startswith("hand loop ran at ")
    assert "of 30 Hz" in outcome.warnings[0]
    run = open_run(tmp_path / "run")
    assert run.status == "complete" and run.warnings == outcome.warnings
    # and where it lagged: one stretch over a period behind (at 60 ms a reading it never catches up),
    # lagging at least 0.77 s by the end (30 readings of >= 60 ms against a 1 s schedule), from its first
    # readings on
    lag = run.metadata["hand_loop"]
    assert lag["period_ms"] == pytest.approx(1e3 / 30, abs=1e-3) and lag["times_behind"] == 1
    assert lag["longest_behind_ms"] > 700 and lag["behind_from_s"][0] < 0.5
    from twin.cli import main

    assert main(["info", str(tmp_path / "run")]) == 0
    text = " ".join(capsys.readouterr().out.split())  # rich wraps at the terminal's width
    assert f"behind its schedule 1 time(s), at most {lag['longest_behind_ms']:.0f} ms" in text
