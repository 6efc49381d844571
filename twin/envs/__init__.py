"""Gymnasium environments of the twin (`pip install 'barrett-twin[gym]'`; the sim backend needs [sim]).

Importing this package registers:

- `BarrettTwin/Squeeze-v0`: the squeeze task on the twin (deterministic for a `reset(seed=...)`);
- `BarrettTwin/SqueezeRig-v0`: the same task on a rig's devices on wall time (a rig.toml, or the hand's
  URL such as `bh8emu://` for the in-process emulated hand); declared nondeterministic, as real time is;
- `BarrettTwin/SqueezeNormalized-v0`: the twin's squeeze task with actions in [-1, 1] and observations as
  fractions of the devices' ranges, for learning libraries (twin.envs.normalized); the raw ids above stay
  in device units for hardware work.

The task, the observations and the actions are described in twin.envs.squeeze.
"""

from gymnasium.envs.registration import register, registry

from twin.envs.squeeze import EPISODE_STEPS, SqueezeEnv, SqueezeTask

__all__ = ["EPISODE_STEPS", "SqueezeEnv", "SqueezeTask"]

if "BarrettTwin/Squeeze-v0" not in registry:
    register(
        id="BarrettTwin/Squeeze-v0",
        entry_point="twin.envs.squeeze:SqueezeEnv",
        max_episode_steps=EPISODE_STEPS,
        kwargs={"backend": "sim"},
    )
    register(
        id="BarrettTwin/SqueezeRig-v0",
        entry_point="twin.envs.squeeze:SqueezeEnv",
        max_episode_steps=EPISODE_STEPS,
        nondeterministic=True,
        kwargs={"backend": "hardware"},
    )
if "BarrettTwin/SqueezeNormalized-v0" not in registry:
    register(
        id="BarrettTwin/SqueezeNormalized-v0",
        entry_point="twin.envs.normalized:make_normalized_squeeze",
        max_episode_steps=EPISODE_STEPS,
        kwargs={"backend": "sim"},
    )
