"""Samples where a finger sat at the safety layer's fingertip-force cap are censored: the layer, not the
object, shaped them (it stopped the finger closing), so no fit takes them; a run is identified from its
uncapped samples, or refused in one line where too few are left."""

from pathlib import Path

import numpy as np
import pytest
from twin.experiments.compress import PHASES, CompressController, CompressProfile

from twin import units
from twin.cli import main
from twin.identify.identify import MAX_CAPPED_FRACTION, compression_window, identify_run, squeeze_stiffness
from twin.identify.reaction import IdentificationError
from twin.identify.signals import load_signals
from twin.recording.reader import open_run
from twin.safety import SafetyLayer, SafetyLimits
from twin.session import run_experiment
from twin.sim.backend import SimBackend
from twin.sim.foam import get_object


def _record(path: Path, limit_kg: float = units.FINGERTIP_FORCE_LIMIT_KG) -> Path:
    """The default block run as it was before the envelope rule (the bare wave on every finger)."""
    profile = CompressProfile(envelope=False)
    run_experiment(
        backend=SimBackend(get_object("block")),
        controller=CompressController(profile),
        phases=PHASES,
        duration_s=10.0,
        run_dir=path,
        experiment={"name": "compress", "object": "block", "profile": profile.to_json()},
        argv=["test"],
        safety=SafetyLayer(SafetyLimits(max_fingertip_force_kg=limit_kg)),
    )
    return path


@pytest.fixture(scope="module")
def capped_run(tmp_path_factory) -> Path:
    """The bare wave's default block run: the thumb reaches the 2 kg cap in every cycle."""
    return _record(tmp_path_factory.mktemp("censoring") / "capped")


@pytest.mark.slow
def test_a_capped_run_is_identified_from_its_uncapped_samples_and_says_how_many_it_left_out(capped_run):
    run = open_run(capped_run)
    hand = run.stream("hand")
    window, _ = compression_window(load_signals(capped_run))
    at_cap = hand["force_kg"][:, :3] >= run.metadata["force_cap"]["limit_kg"]
    expected = int((at_cap.any(axis=1) & window).sum())
    assert expected > 0 and at_cap[window][:, :2].sum() == 0  # the thumb's, as on the run

    ident = identify_run(capped_run)
    assert ident.censored == expected
    assert ident.to_json()["censored_at_force_cap"] == expected
    assert any("F3" in note and "censored" in note for note in ident.notes)
    for finger in ident.fingers:  # no fit took a capped sample
        assert finger.fit.samples == int(window.sum()) - expected
        capped_times = hand.t_s[at_cap.any(axis=1) & window]
        assert not np.isin(finger.t_s, capped_times).any()
    s, sigma, _ = squeeze_stiffness(load_signals(capped_run))
    assert s > 0 and np.isfinite(sigma)


@pytest.mark.slow
def test_a_run_mostly_at_the_cap_is_refused_in_one_line(tmp_path: Path, capsys):
    """A rig whose cap sits at 0.5 kg (eq. 3 at the 0.2 N*m balanced grasp reads 0.47 kg): the squeeze
    holds a finger at it through most of every cycle, so too few samples are the object's."""
    path = _record(tmp_path / "low-cap", limit_kg=0.5)
    signals = load_signals(path)
    window, _ = compression_window(signals)
    assert signals.at_cap[window].any(axis=1).mean() > MAX_CAPPED_FRACTION
    with pytest.raises(IdentificationError, match="fingertip-force cap"):
        identify_run(path)
    assert main(["identify", str(path), "--no-progress"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("twin: error:") and "fingertip-force cap" in err[0], err
