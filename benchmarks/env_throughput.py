"""Steps per second of the Gymnasium environment (twin.envs, `BarrettTwin/Squeeze-v0`, the sim backend).

One environment stepped in this process, then Gymnasium's AsyncVectorEnv with 1 and with 2 worker
processes (one per core on the reference machine). The actions are drawn from the action space (seeded):
fingers sent anywhere in their range, so episodes end (a finger closing on nothing) and are reset inside
the count, as in training. Steps counted are environment steps, summed over the vector's environments;
each is 1/30 s of the twin's time.
"""

from __future__ import annotations

import os
import time

import gymnasium as gym
import numpy as np

ENV_ID = "BarrettTwin/Squeeze-v0"


def _single(steps: int) -> dict:
    import twin.envs  # noqa: F401

    env = gym.make(ENV_ID)
    env.action_space.seed(0)
    env.reset(seed=0)
    resets = 0
    t0 = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
            resets += 1
    wall = time.perf_counter() - t0
    env.close()
    return {"setup": "1 env, in process", "envs": 1, "steps": steps, "resets": resets, "wall_s": wall}


def _make() -> gym.Env:
    import twin.envs  # noqa: F401  (in the worker process)

    return gym.make(ENV_ID)


def _vector(n: int, steps: int) -> dict:
    envs = gym.vector.AsyncVectorEnv([_make] * n, context="spawn")
    envs.action_space.seed(0)
    envs.reset(seed=list(range(n)))
    resets = 0
    t0 = time.perf_counter()
    for _ in range(steps // n):
        _, _, terminated, truncated, _ = envs.step(envs.action_space.sample())
        resets += int(np.sum(terminated | truncated))
    wall = time.perf_counter() - t0
    envs.close()
    return {
        "setup": f"AsyncVectorEnv, {n} env{'s' if n > 1 else ''}",
        "envs": n,
        "steps": steps // n * n,
        "resets": resets,
        "wall_s": wall,
    }


def run(quick: bool = False) -> list[dict]:
    """Each setup's steps/s."""
    steps = 60 if quick else 1200
    load_before = os.getloadavg()[0]
    rows = [_single(steps), _vector(1, steps), _vector(2, steps)]
    for row in rows:
        row["steps_per_s"] = row["steps"] / row["wall_s"]
        row["load_before"] = load_before
    return rows


def to_markdown(rows: list[dict]) -> str:
    """The section of BENCHMARKS.md."""
    base = rows[0]["steps_per_s"]
    lines = [
        "## Gymnasium environment throughput (`benchmarks/env_throughput.py`)",
        "",
        "`BarrettTwin/Squeeze-v0` on the sim, random actions from the action space (episodes end and are "
        "reset inside the count). Each step is one 1/30 s period of the hand's loop.",
        "",
        "| setup | env steps | resets | wall (s) | steps/s | vs 1 env in process | real-time factor |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        lines.append(
            f"| {r['setup']} | {r['steps']} | {r['resets']} | {r['wall_s']:.1f} | {r['steps_per_s']:.0f} | "
            f"{r['steps_per_s'] / base:.2f}x | {r['steps_per_s'] / 30:.1f}x |"
        )
    lines += [
        "",
        f"The machine's 1-minute load average when this started: {rows[0]['load_before']:.1f} on "
        f"{os.cpu_count()} cores. The second environment only pays off with a core to itself: on a machine "
        "already busy the two workers share what is left, and the figure says so.",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    print(to_markdown(run()))
