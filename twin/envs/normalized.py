"""The squeeze task in the units a learning library expects: `BarrettTwin/SqueezeNormalized-v0`.

The raw env (twin.envs.squeeze) speaks the devices' units: set points of 0-17,800 counts, readings up to
32,767. A Gaussian policy starts near 0 and explores a few counts around it, so its fingers never close.
This variant composes Gymnasium's own wrappers over the same env; nothing else changes (task, reward,
safety layer, determinism):

- actions in [-1, 1], mapped linearly (RescaleAction, in float32) onto the safety layer's finger
  set-point range: -1 is open (0 counts), +1 the firmware's largest set point, 0 half closed; an action
  outside [-1, 1] is refused by the safety layer, as in the raw env (SB3 clips its own);
- observations as float32 fractions of each device's range (TransformObservation), from twin.units and
  the safety limits: positions / the firmware's largest position (the spread's: 180 degrees),
  velocities / the safety layer's fastest command (in counts per velocity sample, so +-1 at full
  speed), strain gauges and taxels / their full scale. Each space is the exact image of the raw one
  (positions may read -0.1 to 1.1, as the raw space allows 10 % beyond the range; a velocity spike
  may read beyond +-1).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import RescaleAction, TransformAction, TransformObservation

from twin import units
from twin.envs.squeeze import SqueezeEnv
from twin.interface.devices import TAXEL_COUNT_MAX
from twin.safety import SafetyLimits


def observation_scales(limits: SafetyLimits | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each observation's (offset, full scale) in device counts: normalised = (raw - offset) / scale."""
    limits = limits or SafetyLimits()
    velocity_full = limits.max_velocity_counts_s * units.VELOCITY_SAMPLE_TIME_S  # counts per sample
    return {
        "position_counts": (
            np.zeros(4),
            np.array([units.FINGER_MAX_COUNTS] * 3 + [units.SPREAD_FULL_COUNTS], dtype=np.float64),
        ),
        "velocity_counts": (np.zeros(4), np.full(4, velocity_full)),
        "strain_counts": (np.full(3, float(units.SG_MIN)), np.full(3, float(units.SG_MAX - units.SG_MIN))),
        "tactile_counts": (np.zeros(1), np.full(1, float(TAXEL_COUNT_MAX))),
    }


SCALES = observation_scales()
"""The scales of the registered env: the default safety limits, which SqueezeEnv's action space is built
from."""


def _scale(
    obs: dict[str, np.ndarray], scales: dict[str, tuple[np.ndarray, np.ndarray]]
) -> dict[str, np.ndarray]:
    """Raw readings (counts) -> float32 fractions of each device's range."""
    return {
        name: ((np.asarray(value, dtype=np.float64) - scales[name][0]) / scales[name][1]).astype(np.float32)
        for name, value in obs.items()
    }


def to_device_ranges(obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A raw observation (counts) as float32 fractions of the devices' ranges (SCALES).

    A module-level function, not a closure: the wrapper's spec holds it, and Gymnasium re-makes an env
    from its spec (the env checker does) by comparing the wrappers' arguments, and pickles it for workers."""
    return _scale(obs, SCALES)


def normalized_observation_space(
    raw: spaces.Dict, scales: dict[str, tuple[np.ndarray, np.ndarray]]
) -> spaces.Dict:
    """The raw Dict space mapped through the same scaling as the readings (its exact image)."""
    out = {}
    for name, box in raw.spaces.items():
        low = _scale({name: box.low}, scales)[name]
        high = _scale({name: box.high}, scales)[name]
        out[name] = spaces.Box(low, high, shape=box.shape, dtype=np.float32)
    return spaces.Dict(out)


def as_float32(action: np.ndarray) -> np.ndarray:
    """An action as float32, before RescaleAction maps it: its float32 arithmetic maps +1 onto the top set
    point exactly, where float64 lands 5e-5 counts above it and the safety layer would refuse the command."""
    return np.asarray(action, dtype=np.float32)


def make_normalized_squeeze(**kwargs: Any) -> gym.Env:
    """The squeeze env (`SqueezeEnv(**kwargs)`) with actions in [-1, 1] and observations in device ranges.

    The registration's entry point for `BarrettTwin/SqueezeNormalized-v0`; any SqueezeEnv keyword works
    (`object_name=`, `backend=`, ...)."""
    env = RescaleAction(SqueezeEnv(**kwargs), np.float32(-1.0), np.float32(1.0))
    env = TransformAction(env, as_float32, env.action_space)
    return TransformObservation(
        env, to_device_ranges, normalized_observation_space(env.observation_space, SCALES)
    )
