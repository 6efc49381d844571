"""The squeeze task as a Gymnasium environment, on the twin or on a rig's devices.

Task: close the three fingers on the foam and hold a grasp in which every finger's distal load (eq. 2's
torque above its no-load value) is `target_nm` (0.2 N*m, the compress procedure's balanced grasp)
within `tolerance_nm`, for `hold_steps` readings in a row (success), without losing the object: a finger
that reaches 95 % of its travel with less than half the contact load has closed on nothing (failure).

- Observations, in the units the devices report: `position_counts` (4: F1, F2, F3, spread encoders),
  `velocity_counts` (4), `strain_counts` (3, 0-255), `tactile_counts` (162 taxels, 15-bit; zeros where
  the backend has no pads).
- Actions: the three fingers' position set points (encoder counts); the spread stays at 0. Each goes
  through the run's SafetyLayer (the rig's limits): out of range is refused (UnsafeCommandError), a
  finger at the fingertip force limit is held, as in every `twin run`.
- One step is one period of the hand's loop (30 Hz): command, let the world advance, read.
- Reward per step: -mean |load - target| / target over the fingers; +10 on success, -10 on failure.

The sim backend is rebuilt at every reset from the seed (deterministic); a rig is connected at the
first reset and opened (fingers to 0) at each later one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from twin import units
from twin.interface.backend import Backend
from twin.interface.devices import N_TAXELS, TAXEL_COUNT_MAX, HandCommand, HandReading
from twin.safety import SafetyLayer

EPISODE_STEPS = 300
"""10 s of the hand's 30 Hz loop: the registered episodes are truncated there."""
OPEN_COUNTS = 200
"""A finger below this many counts counts as open at reset."""
OPEN_STALL_S = 5.0
"""A reset waits for the fingers to open while they still move: it gives up once none of those not yet
open has come OPEN_PROGRESS_COUNTS nearer in this long (a full close undone takes ~1.7 s at the task's
10,000 counts/s). Progress, not a deadline: an emulated twin running behind wall time on a loaded host
opens its fingers late, not never."""
OPEN_PROGRESS_COUNTS = 50
"""Movement that counts as progress while opening: well above the encoders' jitter of a few counts."""
OPEN_TIMEOUT_S = 60.0
"""The longest a reset waits for the fingers to open, moving or not."""
VELOCITY_LIMIT_COUNTS = 32767
"""Bounds of a velocity reading (the wire's signed 16 bits)."""


@dataclass(frozen=True)
class SqueezeTask:
    """The squeeze task's constants (see the module docstring)."""

    target_nm: float = 0.2
    tolerance_nm: float = 0.03
    hold_steps: int = 10
    contact_nm: float = 0.1
    max_velocity_counts_s: float = 10_000.0
    success_reward: float = 10.0
    failure_reward: float = -10.0

    def load_nm(self, reading: HandReading) -> np.ndarray:
        """Each finger's distal torque above its no-load value (eq. 2), N*m."""
        return units.strain_to_torque_nm(reading.strain_counts) - units.strain_to_torque_nm(
            units.NO_LOAD_STRAIN
        )


class SqueezeEnv(gym.Env):
    """Squeeze the foam to a target grasp load: the twin (`backend="sim"`) or a rig (`"hardware"`)."""

    metadata = {"render_modes": []}  # noqa: RUF012  (gymnasium's class attribute)

    def __init__(
        self,
        backend: str = "sim",
        *,
        object_name: str = "block",
        rig: str | Path | None = None,
        hand: str | None = None,
        task: SqueezeTask | None = None,
    ) -> None:
        """`object_name`: the library foam in the twin's hand. `rig` (a rig.toml) or `hand` (a port or
        URL; `bh8emu://?object=block` by default) for the hardware backend."""
        if backend not in ("sim", "hardware"):
            raise ValueError(f"backend must be 'sim' or 'hardware', got {backend!r}")
        self.backend_name = backend
        self.object_name = object_name
        self.rig = rig
        self.hand = hand if hand is not None or rig is not None else f"bh8emu://?object={object_name}"
        self.task = task or SqueezeTask()
        self._backend: Backend | None = None
        self._safety = SafetyLayer()
        self._held = 0
        self._last: HandReading | None = None
        self._tick_s = 0.0
        lo, hi = self._safety.limits.finger_counts
        self.action_space = spaces.Box(np.float32(lo), np.float32(hi), shape=(3,), dtype=np.float32)
        counts_hi = np.array([units.FINGER_MAX_COUNTS] * 3 + [units.SPREAD_FULL_COUNTS], dtype=np.int32)
        self.observation_space = spaces.Dict(
            {
                "position_counts": spaces.Box(
                    -counts_hi // 10, counts_hi + counts_hi // 10, shape=(4,), dtype=np.int32
                ),
                "velocity_counts": spaces.Box(
                    -VELOCITY_LIMIT_COUNTS, VELOCITY_LIMIT_COUNTS, shape=(4,), dtype=np.int32
                ),
                "strain_counts": spaces.Box(units.SG_MIN, units.SG_MAX, shape=(3,), dtype=np.int32),
                "tactile_counts": spaces.Box(0, TAXEL_COUNT_MAX, shape=(N_TAXELS,), dtype=np.int32),
            }
        )

    def _observe(self) -> dict[str, np.ndarray]:
        backend = self._backend
        reading = backend.hand.read()
        self._safety.observe(reading)
        self._last = reading
        tactile = (
            np.zeros(N_TAXELS, dtype=np.int32)
            if backend.tactile is None
            else np.asarray(backend.tactile.read().counts, dtype=np.int32)
        )
        return {
            "position_counts": np.asarray(reading.position_counts, dtype=np.int32).copy(),
            "velocity_counts": np.asarray(reading.velocity_counts, dtype=np.int32).copy(),
            "strain_counts": np.asarray(reading.strain_counts, dtype=np.int32).copy(),
            "tactile_counts": tactile.copy(),
        }

    def _advance(self) -> None:
        """On to the next tick of the hand's loop (on wall time: paced, not one period after the read)."""
        self._tick_s += self._backend.hand.spec.period_s
        self._backend.clock.advance_to(self._tick_s)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """A fresh twin for the seed (sim), or the rig with its fingers opened (hardware)."""
        super().reset(seed=seed)
        self._held = 0
        self._tick_s = 0.0
        if self.backend_name == "sim":
            from twin import api

            if self._backend is not None:
                self._backend.disconnect()
            self._backend = api.sim_backend(self.object_name, seed=int(self.np_random.integers(2**31)))
            self._backend.connect()
            self._backend.clock.start()
        elif self._backend is None:
            from twin import api

            self._backend = api.hardware_backend(self.rig, hand=self.hand)
            self._safety = SafetyLayer(self._backend.safety_limits())
            self._backend.connect()
            self._backend.clock.start()
        else:
            self._tick_s = self._backend.clock.now()
            self._open_fingers()
        return self._observe(), {"backend": self.backend_name}

    def _open_fingers(self, stall_s: float = OPEN_STALL_S, timeout_s: float = OPEN_TIMEOUT_S) -> None:
        """Send every finger to 0 and wait (at the loop's rate) until they are nearly there; a hand whose
        fingers stop short of open is an error, not an episode that starts closed."""
        command = HandCommand(np.zeros(4), max_velocity_counts_s=self.task.max_velocity_counts_s)
        period_s = self._backend.hand.spec.period_s
        best = np.full(3, np.inf)  # each finger's nearest approach to open so far
        since_progress = 0
        for _ in range(int(timeout_s / period_s)):
            self._backend.hand.command(self._safety.check(command))
            self._advance()
            position = self._backend.hand.read().position_counts[:3]
            if (position < OPEN_COUNTS).all():
                return
            moved = (position < best - OPEN_PROGRESS_COUNTS) & (position >= OPEN_COUNTS)
            since_progress = 0 if moved.any() else since_progress + 1
            best = np.where(moved, position, best)
            if since_progress * period_s >= stall_s:
                break
        raise RuntimeError(
            f"reset: the fingers stopped short of open (at {position.tolist()} counts; open is below "
            f"{OPEN_COUNTS}): is something blocking the hand?"
        )

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """Send the set points through the safety layer, advance one period, read, score."""
        if self._backend is None:
            raise RuntimeError("call reset() before step()")
        target = np.append(np.asarray(action, dtype=np.float64).reshape(3), 0.0)
        command = HandCommand(target, max_velocity_counts_s=self.task.max_velocity_counts_s)
        self._backend.hand.command(self._safety.check(command))
        self._advance()
        obs = self._observe()
        task = self.task
        load = task.load_nm(self._last)
        reward = -float(np.mean(np.abs(load - task.target_nm))) / task.target_nm
        within = bool((np.abs(load - task.target_nm) <= task.tolerance_nm).all())
        self._held = self._held + 1 if within else 0
        closed = obs["position_counts"][:3] >= 0.95 * units.FINGER_FULL_COUNTS
        missed = bool((closed & (load < task.contact_nm / 2)).any())
        success = self._held >= task.hold_steps
        if success:
            reward += task.success_reward
        elif missed:
            reward += task.failure_reward
        info = {"load_nm": load, "success": success, "missed": missed}
        return obs, reward, success or missed, False, info

    def close(self) -> None:
        """Disconnect the devices (idles the hand); safe to call twice."""
        if self._backend is not None:
            backend, self._backend = self._backend, None
            backend.disconnect()
