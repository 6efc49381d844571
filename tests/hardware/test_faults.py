"""The fault matrix: each fault injected by the emulator -> recovered, or a safe stop with a clear
error; either way the recording up to the fault is intact (zero samples lost before it).

The compress experiment runs on the hardware backend against a twin-backed emulator on TCP. Each
period the driver makes one feedback cycle (A) and one control cycle (c), so RealTime reply 2k-1 is
the k-th sample's feedback and reply 2k its command's acknowledgement.
"""

from pathlib import Path

import numpy as np
import pytest
from twin.experiments.compress import PHASES, CompressController
from twin.hardware.backend import HardwareBackend
from twin.hardware.bh262.driver import SCHEDULING_MARGIN_S, PortSettings
from twin.hardware.bh262.emulator import make_hand_emulator
from twin.hardware.rig_config import HandPortConfig, RigConfig

from twin.recording import open_run
from twin.session import run_experiment

DURATION_S = 3.0
SAMPLES = int(DURATION_S * 30) + 1
FAULT_AT = 31  # the 16th sample's feedback: 15 samples are recorded before it


def terminated_and_restored(commands: list[str]) -> bool:
    """After the last LOOP: T reached the hand, then the rate went back to 9600 for the next session."""
    last_loop = max(i for i, c in enumerate(commands) if c.endswith("LOOP"))
    after = commands[last_loop:]
    return "T" in after and after.index("T") < after.index("PSET BAUD 96")


def run_with_faults(faults: str, run_dir: Path, object_name: str | None = "block", **port_settings: float):
    events: list[str] = []
    emulator = make_hand_emulator(object_name, faults=faults, on_event=events.append)
    emulator.events = events  # what the emulator saw, for a failing test's message
    url = emulator.serve_tcp(0)
    port = PortSettings(url=url, switch_baud=38400, baud_switch_wait_s=0.05, **port_settings)
    backend = HardwareBackend(RigConfig(hand_port=HandPortConfig(port=port)))
    error = None
    try:
        run_experiment(
            backend=backend,
            controller=CompressController(),
            phases=PHASES,
            duration_s=DURATION_S,
            run_dir=run_dir,
            experiment={"name": "compress", "faults": faults},
            argv=["test"],
        )
    except Exception as exc:  # the safe stops re-raise after closing the recording
        error = exc
    finally:
        emulator.close()
    return open_run(run_dir), error, emulator


RECOVERED = [
    "garbage@31",  # noise before a feedback block
    "garbage@32",  # noise before a command's '*'
    "drop@31",  # no feedback at all
    "drop@32",  # no acknowledgement of a command
    "partial@31",  # half a block
    # Later than the wire time plus the scheduling allowance (SCHEDULING_MARGIN_S) by far more than a
    # busy runner's scheduling delays: the late bytes arrive while recovering.
    f"late@31:{SCHEDULING_MARGIN_S + 0.5:g}",
]


@pytest.mark.slow
@pytest.mark.parametrize("faults", RECOVERED)
def test_recoverable_faults_lose_no_sample(faults: str, tmp_path: Path):
    run, error, emulator = run_with_faults(faults, tmp_path / "run")
    assert error is None, f"emulator: {emulator.failed()}; {error}; events: {emulator.events[-6:]}"
    assert run.status == "complete"
    hand = run.stream("hand")
    assert len(hand.t_s) == SAMPLES
    assert np.all(np.diff(hand.t_s) > 0)
    assert len(run.metadata["hand_recoveries"]) >= 1
    assert emulator.firmware.commands.count("1234LOOP") >= 2  # LOOP re-entered after the fault


def test_a_slightly_late_reply_is_just_late(tmp_path: Path):
    # 50 ms late against the default allowance (SCHEDULING_MARGIN_S, 500 ms): a late reply within it is
    # a valid one, not a lost one (the 450 ms left over absorb a loaded runner's scheduling).
    run, error, emulator = run_with_faults("late@31:0.05", tmp_path / "run")
    assert error is None and run.status == "complete", f"emulator: {emulator.failed()}; {error}"
    assert len(run.stream("hand").t_s) == SAMPLES
    assert run.metadata["hand_recoveries"] == []


SAFE_STOPS = [
    ("err@31:8192", "OVER_TEMPERATURE"),  # the hand reports an error: stop, name it
    ("vanish@31", "the hand's port socket://"),  # the port disappears: "... was lost: ..."
    ("mute@31", "no valid feedback from the hand for 3 cycles in a row"),  # the watchdog
]


@pytest.mark.slow
@pytest.mark.parametrize(("faults", "message"), SAFE_STOPS)
def test_unrecoverable_faults_stop_safely_with_the_data_intact(faults: str, message: str, tmp_path: Path):
    run, error, _ = run_with_faults(faults, tmp_path / "run")
    assert error is not None and message in str(error)
    assert run.status == "failed" and message in run.info["error"]
    hand = run.stream("hand")
    assert len(hand.t_s) == (FAULT_AT - 1) // 2  # every sample before the fault, none after
    assert np.all(np.diff(hand.t_s) > 0)
    assert len(run.stream("command").t_s) == (FAULT_AT - 1) // 2


def test_watchdog_terminates_the_motors_once_the_hand_answers_again(tmp_path: Path):
    """Feedback stops for 3 s: the watchdog gives up after about 2 s ((3 + 1) x SCHEDULING_MARGIN_S), and
    idle() keeps sending CRs (1 s apart, 3 tries) until the hand answers, so T reaches it."""
    run, error, emulator = run_with_faults("mute@31:3", tmp_path / "run")
    assert "no valid feedback" in str(error) and run.status == "failed"
    assert terminated_and_restored(emulator.firmware.commands)
    assert emulator.firmware.loop is None


def test_err_reply_idles_the_hand_with_t(tmp_path: Path):
    _, error, emulator = run_with_faults("err@31:16", tmp_path / "run")
    assert "COULD_NOT_REACH_POSITION" in str(error)
    assert terminated_and_restored(emulator.firmware.commands)


def test_a_vanished_port_is_reported_as_lost_not_as_a_watchdog_stop(tmp_path: Path):
    run, error, _ = run_with_faults("vanish@31", tmp_path / "run")
    reason = str(error).split(";")[0]  # the stop itself, before what became of the hand
    assert "was lost" in reason and "no valid feedback" not in reason
    assert run.status == "failed" and "was lost" in run.info["error"]
    assert "motors terminated" not in str(error) and "the hand was idled" not in str(error)


def test_a_muted_hand_is_a_watchdog_stop_and_never_claimed_idled(tmp_path: Path):
    """The hand never answers again: the watchdog stops the run and T cannot get through, so the error
    says so instead of claiming the motors were terminated."""
    run, error, emulator = run_with_faults("mute@31", tmp_path / "run", timeout_s=0.3)
    message = str(error)
    assert "no valid feedback from the hand for 3 cycles in a row" in message
    assert "T (terminate) was not sent" in message
    assert "motors terminated" not in message and "the hand was idled" not in message
    assert "T (terminate) was not sent" in run.info["error"]
    assert "T" not in emulator.firmware.commands[emulator.firmware.commands.index("1234LOOP") :]
