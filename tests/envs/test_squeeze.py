"""The Gymnasium environment on the twin and on the emulated rig (hand and pads over ptys, wall time):
Gymnasium's own checker, seeded determinism, the safety layer on actions, and a scripted policy that
reaches the task's success on both."""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from twin.hardware.rig_emulator import RigEmulator

import twin.envs  # noqa: F401  (registers the ids)
from twin import units
from twin.envs.squeeze import OPEN_COUNTS
from twin.safety import UnsafeCommandError

FIELDS = ("position_counts", "velocity_counts", "strain_counts", "tactile_counts")


def squeeze_policy(obs: dict, state: dict) -> np.ndarray:
    """Close at 400 counts per step until a finger feels the foam, then servo its load to 0.2 N*m."""
    load = units.strain_to_torque_nm(obs["strain_counts"]) - units.strain_to_torque_nm(units.NO_LOAD_STRAIN)
    if "set" not in state:
        state["set"], state["touch"] = obs["position_counts"][:3].astype(float), np.zeros(3, dtype=bool)
    state["touch"] |= load > 0.1
    step = np.where(state["touch"], np.clip(2000 * (0.2 - load) / 30, -100, 100), 400.0)
    state["set"] = np.clip(state["set"] + step, 0, units.FINGER_FULL_COUNTS)
    return state["set"].astype(np.float32)


def episode(env: gym.Env, **reset: object) -> tuple[int, dict, list[float]]:
    obs, _ = env.reset(**reset)
    state: dict = {}
    rewards = []
    for k in range(1, 301):
        obs, reward, terminated, truncated, info = env.step(squeeze_policy(obs, state))
        rewards.append(reward)
        if terminated or truncated:
            return k, info, rewards
    return k, info, rewards


def test_check_env_and_the_squeeze_task_on_the_twin():
    env = gym.make("BarrettTwin/Squeeze-v0")
    check_env(env.unwrapped, skip_render_check=True)
    steps, info, rewards = episode(env, seed=3)
    assert info["success"] and not info["missed"]
    assert np.abs(info["load_nm"] - 0.2).max() <= 0.03
    assert 30 < steps < 300 and rewards[-1] > 9 and max(rewards[:-1]) <= 0
    obs, _ = env.reset(seed=3)
    assert obs["tactile_counts"].shape == (162,) and obs["position_counts"][:3].max() == 0
    env.close()


def test_reset_with_a_seed_replays_the_same_episode():
    env = gym.make("BarrettTwin/Squeeze-v0")
    runs = []
    for seed in (7, 7, 8):
        obs, _ = env.reset(seed=seed)
        trace = [obs["strain_counts"].copy()]
        for k in range(20):
            obs, *_ = env.step(np.full(3, 600.0 * k, dtype=np.float32))
            trace.append(np.concatenate([obs[name] for name in FIELDS]))
        runs.append(trace)
    assert all(np.array_equal(a, b) for a, b in zip(runs[0], runs[1], strict=True))
    assert not all(np.array_equal(a, b) for a, b in zip(runs[0], runs[2], strict=True))  # the noise differs
    env.close()


def test_an_action_outside_the_rig_limits_is_refused_by_the_safety_layer():
    env = gym.make("BarrettTwin/Squeeze-v0").unwrapped
    env.reset(seed=0)
    with pytest.raises(UnsafeCommandError, match="outside"):
        env.step(np.array([20_000, 0, 0], dtype=np.float32))
    env.close()


def test_check_env_and_the_squeeze_task_on_the_emulated_rig(tmp_path: Path):
    with RigEmulator("block", seed=0) as emulator:
        emulator.serve("pty")
        rig = emulator.write_rig_file(tmp_path / "rig.toml")
        env = gym.make("BarrettTwin/SqueezeRig-v0", rig=rig)
        assert env.spec.nondeterministic  # wall time: declared so, and checked for everything else
        try:
            check_env(env.unwrapped, skip_render_check=True)
            steps, info, rewards = episode(env)
            # Every step scored as the task says, and the episode ended as the task says: on success,
            # on a miss, or truncated. (Whether the policy's grasp settles within the episode depends on
            # how late a loaded host runs the loop: the twin run above checks the task itself.)
            load = info["load_nm"]
            score = -float(np.mean(np.abs(load - 0.2))) / 0.2
            bonus = 10 if info["success"] else -10 if info["missed"] else 0
            assert rewards[-1] == pytest.approx(score + bonus)
            assert info["success"] or info["missed"] or steps == 300
            assert load[:2].max() > 0.1  # the fingers closed on the foam through the bridge
            obs, _ = env.reset()  # the fingers opened again on the same connection
        except Exception as exc:  # a lost port: say what the emulator saw
            raise AssertionError(
                f"emulator: {emulator.hand.failed()}; tactile: {emulator.tactile.failed()}"
            ) from exc
        assert obs["position_counts"][:3].max() < OPEN_COUNTS
        assert obs["tactile_counts"].max() > 0  # the pads are there, over their own port
        env.close()
