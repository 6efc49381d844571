"""The normalised squeeze env (`BarrettTwin/SqueezeNormalized-v0`): both env checkers pass without their
normalisation warnings, its actions and observations are the raw env's through the documented scaling
(same seed, same episode), and docs/api.md's Stable-Baselines3 example runs as written."""

import re
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env, check_space_limit
from stable_baselines3.common import env_checker as sb3_env_checker

import twin.envs  # noqa: F401  (registers the ids)
from twin import units
from twin.envs.normalized import SCALES
from twin.interface.devices import TAXEL_COUNT_MAX
from twin.safety import SafetyLimits, UnsafeCommandError

API_MD = Path(__file__).resolve().parents[2] / "docs" / "api.md"
WRAPPED_NOTICE = "is different from the unwrapped version"  # gymnasium's note on any wrapped env


def test_both_env_checkers_pass_without_normalisation_warnings():
    env = gym.make("BarrettTwin/SqueezeNormalized-v0")
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # The wrappers are the point, so the checkers see the env as gym.make returns it (gymnasium
        # then notes that it is wrapped: the only warning allowed).
        check_env(env, skip_render_check=True)
        sb3_env_checker.check_env(env, warn=True)
    messages = [str(w.message) for w in caught if WRAPPED_NOTICE not in str(w.message)]
    assert messages == []
    env.close()
    raw = gym.make(
        "BarrettTwin/Squeeze-v0"
    )  # the raw env's spaces draw both warnings: the test would see them
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_space_limit(raw.action_space, "action")  # the check inside gymnasium's check_env
        sb3_env_checker.check_env(raw, warn=True)
    assert sum("symmetric and normalized" in str(w.message) for w in caught) == 2
    raw.close()


def test_the_scales_come_from_the_device_ranges_and_the_safety_limits():
    limits = SafetyLimits()
    assert SCALES["position_counts"][1].tolist() == [units.FINGER_MAX_COUNTS] * 3 + [units.SPREAD_FULL_COUNTS]
    assert SCALES["velocity_counts"][1][0] == limits.max_velocity_counts_s * units.VELOCITY_SAMPLE_TIME_S
    assert SCALES["strain_counts"][1][0] == units.SG_MAX - units.SG_MIN
    assert SCALES["tactile_counts"][1][0] == TAXEL_COUNT_MAX
    space = gym.make("BarrettTwin/SqueezeNormalized-v0").observation_space
    assert space["strain_counts"].low.min() == 0 and space["strain_counts"].high.max() == 1
    assert space["tactile_counts"].high.max() == 1
    assert space["position_counts"].high[0] == pytest.approx(1.1)  # the raw space's 10 % beyond travel


def test_the_normalised_env_is_the_raw_env_rescaled():
    """Same seed, actions a and their set points in counts: the same episode, observations scaled."""
    lo, hi = SafetyLimits().finger_counts
    norm = gym.make("BarrettTwin/SqueezeNormalized-v0")
    raw = gym.make("BarrettTwin/Squeeze-v0")
    obs_n, _ = norm.reset(seed=5)
    obs_r, _ = raw.reset(seed=5)
    actions = [np.array([a, a, a], dtype=np.float32) for a in np.linspace(-1, 1, 15)]
    actions += [np.array([1.0, 1.0, 1.0])]  # float64 +1 is the top set point exactly, not refused
    for a in actions:
        counts = (lo + (np.asarray(a, dtype=np.float64) + 1) / 2 * (hi - lo)).astype(np.float32)
        obs_n, reward_n, *_ = norm.step(a)
        obs_r, reward_r, *_ = raw.step(counts)
        assert reward_n == reward_r
        for name, (offset, scale) in SCALES.items():
            assert obs_n[name].dtype == np.float32
            np.testing.assert_allclose(obs_n[name], (obs_r[name] - offset) / scale, rtol=1e-6)
    assert obs_r["position_counts"][:3].min() > 1000  # the fingers did move
    with pytest.raises(UnsafeCommandError, match="outside"):  # beyond [-1, 1] is refused, not clipped
        norm.unwrapped.step(np.full(3, 20_000.0))  # (the raw env underneath)
    with pytest.raises(UnsafeCommandError, match="outside"):
        norm.step(np.array([1.5, 0.0, 0.0], dtype=np.float32))
    norm.close()
    raw.close()


def _docs_example(marker: str) -> str:
    text = API_MD.read_text().split("\n## Learning\n", 1)[1].split("\n## ", 1)[0]
    (example,) = [b for b in re.findall(r"```python\n(.*?)```", text, flags=re.S) if marker in b]
    return example


def test_the_docs_stable_baselines3_example_runs_as_written(tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TWIN_PPO_STEPS", "256")  # a few hundred steps: that it runs, not that it learns
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path / "sb3"))  # else an SB3-<date> folder in /tmp per learn()
    scope: dict = {}
    threads = torch.get_num_threads()
    try:
        exec(compile(_docs_example("stable_baselines3"), "docs/api.md: Learning (PPO)", "exec"), scope)
    finally:
        torch.set_num_threads(threads)  # the example sets 1: not for the tests after it in this process
    model = scope["model"]
    assert model.num_timesteps >= 256
    assert scope["reward"] != 0  # the trained policy stepped the env
