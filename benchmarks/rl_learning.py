"""Does PPO learn the squeeze task? Stable-Baselines3's PPO on `BarrettTwin/SqueezeNormalized-v0` against a
random policy on the same seeds, and the env's steps/s on one and two workers.

PPO (MultiInputPolicy, SB3's defaults but for the rollout length, CPU, seed 0) trains for STEPS env steps;
its episode rewards during training give the learning curve. Then its deterministic policy and a random
policy (the action space's samples, seeded) each play one episode per evaluation seed, the same seeds, so
the same twins. The throughput rows step random actions through SB3's DummyVecEnv (one env in process)
and SubprocVecEnv (two worker processes): the env alone, without the learner.
"""

from __future__ import annotations

import itertools
import os
import tempfile
import time

import gymnasium as gym
import numpy as np

from twin.safety import SafetyLimits

ENV_ID = "BarrettTwin/SqueezeNormalized-v0"
STEPS = 100_000
"""PPO's training budget in env steps: ~11 min of training on 2 cores at a load average of 5 (154 steps/s),
so the whole benchmark stays within 15 min."""
QUICK_STEPS = 1_024
N_STEPS = 1_024
"""PPO's rollout per update, summed over the envs (SB3's default is 2,048 per env)."""
TRAIN_ENVS = 2
"""Training envs, in SubprocVecEnv workers (one per core of the reference machine)."""
EVAL_SEEDS = tuple(range(1000, 1010))
"""reset(seed=...) of the evaluation episodes, the same for PPO and the random policy."""
THROUGHPUT_STEPS = 1_200
TRAIN_SEED = 0


def _make() -> gym.Env:
    import twin.envs  # noqa: F401  (in a worker process too)

    return gym.make(ENV_ID)


def _episode(env: gym.Env, seed: int, act) -> tuple[float, int, bool, float]:
    """One episode from reset(seed): its reward, its length, whether it ended in the task's success, and
    the mean finger set point it commanded (counts: what the policy does, in the hand's units)."""
    lo, hi = SafetyLimits().finger_counts
    obs, _ = env.reset(seed=seed)
    total, steps, set_point = 0.0, 0, 0.0
    while True:
        action = np.clip(act(obs), -1, 1)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        set_point += float(np.mean(lo + (action + 1) / 2 * (hi - lo)))
        steps += 1
        if terminated or truncated:
            return total, steps, bool(info["success"]), set_point / steps


def _evaluate(policy, seeds: tuple[int, ...]) -> dict:
    """One episode per seed: `policy(obs) -> action`, or None for the random policy (the action space's
    samples, seeded once for the whole evaluation)."""
    env = _make()
    env.action_space.seed(0)
    act = policy if policy is not None else (lambda obs: env.action_space.sample())
    episodes = [_episode(env, seed, act) for seed in seeds]
    env.close()
    rewards = np.array([e[0] for e in episodes])
    return {
        "rewards": rewards.tolist(),
        "lengths": [e[1] for e in episodes],
        "successes": int(sum(e[2] for e in episodes)),
        "set_point_counts": float(np.mean([e[3] for e in episodes])),
        "mean": float(rewards.mean()),
        "std": float(rewards.std()),
    }


def _train(steps: int) -> tuple[object, dict]:
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    # The policy is a small MLP: torch's threads only fight the env's workers for the cores (on 2 busy
    # cores, 2 threads made training ~10x slower than 1).
    torch.set_num_threads(1)
    vec = make_vec_env(_make, n_envs=TRAIN_ENVS, seed=TRAIN_SEED, vec_env_cls=SubprocVecEnv)
    model = PPO(
        "MultiInputPolicy", vec, n_steps=N_STEPS // TRAIN_ENVS, seed=TRAIN_SEED, device="cpu", verbose=0
    )
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as logs:  # SB3 leaves an empty SB3-<date> folder per learn() in /tmp
        os.environ["SB3_LOGDIR"] = logs
        model.learn(total_timesteps=steps)
    wall = time.perf_counter() - t0
    # Each training episode's reward and where it ended, in env steps summed over the workers.
    ends, rewards = [], []
    for env_rewards, env_lengths in zip(
        vec.env_method("get_episode_rewards"), vec.env_method("get_episode_lengths"), strict=True
    ):
        ends += (np.cumsum(env_lengths) * TRAIN_ENVS).tolist()  # the workers step in lock-step
        rewards += list(env_rewards)
    vec.close()
    order = np.argsort(ends)
    return model, {
        "steps": int(model.num_timesteps),
        "wall_s": wall,
        "episode_end_steps": np.asarray(ends)[order].tolist(),
        "episode_rewards": np.asarray(rewards)[order].tolist(),
    }


def _throughput(workers: int, steps: int) -> dict:
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    cls = DummyVecEnv if workers == 1 else SubprocVecEnv
    vec = cls([_make] * workers)
    vec.seed(0)
    vec.action_space.seed(0)
    vec.reset()
    t0 = time.perf_counter()
    for _ in range(steps // workers):
        vec.step(np.stack([vec.action_space.sample() for _ in range(workers)]))
    wall = time.perf_counter() - t0
    vec.close()
    return {
        "setup": f"{cls.__name__}, {workers} env{'s' if workers > 1 else ''}",
        "steps": steps // workers * workers,
        "wall_s": wall,
        "steps_per_s": steps // workers * workers / wall,
    }


def curve(train: dict, bins: int = 10) -> list[tuple[int, float, int]]:
    """Training episodes' mean reward per bin of env steps: (bin's last step, mean reward, episodes)."""
    ends = np.asarray(train["episode_end_steps"])
    rewards = np.asarray(train["episode_rewards"])
    edges = np.linspace(0, train["steps"], bins + 1)
    out = []
    for lo, hi in itertools.pairwise(edges):
        mine = (ends > lo) & (ends <= hi)
        if mine.any():
            out.append((int(hi), float(rewards[mine].mean()), int(mine.sum())))
    return out


def run(quick: bool = False) -> dict:
    """Train PPO, evaluate it and a random policy on the same seeds, and time the env on 1 and 2 workers."""
    steps = QUICK_STEPS if quick else STEPS
    seeds = EVAL_SEEDS[:2] if quick else EVAL_SEEDS
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    throughput = [
        _throughput(1, 60 if quick else THROUGHPUT_STEPS),
        _throughput(2, 60 if quick else THROUGHPUT_STEPS),
    ]
    random_policy = _evaluate(None, seeds)
    model, train = _train(steps)
    ppo = _evaluate(lambda obs: model.predict(obs, deterministic=True)[0], seeds)
    return {
        "steps": steps,
        "seeds": list(seeds),
        "train": train,
        "ppo": ppo,
        "random": random_policy,
        "throughput": throughput,
        "load_before": load_before,
        "total_wall_s": time.perf_counter() - t0,
    }


def to_markdown(results: dict) -> str:
    """The section of BENCHMARKS.md."""
    ppo, rnd, train = results["ppo"], results["random"], results["train"]
    seeds = results["seeds"]
    lines = [
        "## Learning: PPO on the normalised env (`benchmarks/rl_learning.py`)",
        "",
        f"Stable-Baselines3 PPO (`MultiInputPolicy`, defaults but `n_steps={N_STEPS // TRAIN_ENVS}` per env, "
        f"{TRAIN_ENVS} SubprocVecEnv workers, seed {TRAIN_SEED}, CPU) on `{ENV_ID}` for "
        f"**{train['steps']:,} env steps** ({train['steps'] / 30 / 60:.0f} min of the twin's time) in "
        f"{train['wall_s']:.0f} s. Then one episode per evaluation seed ({seeds[0]}-{seeds[-1]}, "
        "`reset(seed=...)`, the same twins for both), PPO's deterministic policy against random actions "
        "(the action space's samples, seeded). An episode is at most 300 steps; each step costs the mean "
        "relative load error (-1 with no contact), success adds +10 and ends it, a finger closing on "
        "nothing -10 and ends it.",
        "",
        "| policy | mean episode reward | std | successes | mean length (steps) | mean set point (counts) |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, r in (("random", rnd), (f"PPO after {train['steps']:,} steps", ppo)):
        lines.append(
            f"| {name} | {r['mean']:.1f} | {r['std']:.1f} | {r['successes']}/{len(seeds)} | "
            f"{np.mean(r['lengths']):.0f} | {r['set_point_counts']:,.0f} |"
        )
    lines += [
        "",
        "Training episodes' mean reward by env steps (the learning curve; episodes ending in each bin):",
        "",
        "| env steps up to | mean episode reward | episodes |",
        "| ---: | ---: | ---: |",
    ]
    lines += [f"| {step:,} | {mean:.1f} | {count} |" for step, mean, count in curve(train)]
    lines += [
        "",
        "The env alone, random actions, SB3's vector envs (episodes end and reset inside the count):",
        "",
        "| setup | env steps | wall (s) | steps/s |",
        "| --- | ---: | ---: | ---: |",
    ]
    lines += [
        f"| {r['setup']} | {r['steps']} | {r['wall_s']:.1f} | {r['steps_per_s']:.0f} |"
        for r in results["throughput"]
    ]
    lines += [
        "",
        f"The whole benchmark took {results['total_wall_s']:.0f} s; the machine's 1-minute load average when "
        f"it started: {results['load_before']:.1f} on {os.cpu_count()} cores.",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    import sys

    print(to_markdown(run(quick="--quick" in sys.argv)))
