"""One MuJoCo world: model, data, the clutches, and the hooks devices run around every step.

A model too stiff or too damped for its step diverges: MuJoCo then resets the state (mjWARN_BADQACC and
its kin) and puts the time back, so stepping "until t" would never end. Every step is checked, and a
divergence ends in SimulationUnstableError naming the instant and what to change.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import mujoco
import numpy as np

from twin.interface.errors import SimulationUnstableError
from twin.sim.clutch import Clutches

StepHook = Callable[[mujoco.MjData], None]

UNSTABLE_WARNINGS = {
    int(mujoco.mjtWarning.mjWARN_BADQPOS): "position",
    int(mujoco.mjtWarning.mjWARN_BADQVEL): "velocity",
    int(mujoco.mjtWarning.mjWARN_BADQACC): "acceleration",
}
"""MuJoCo's own instability checks (each resets the state): the quantity that went non-finite or huge."""
_UNSTABLE_INDEX = np.array(list(UNSTABLE_WARNINGS))
DEFAULT_HINT = "the model is too stiff or too damped for its physics step"
_MUTED_MESSAGES = ("Nan, Inf or huge value", "Linesearch objective is not convex")


class _MuteDivergence(logging.Filter):
    """Drop MuJoCo's per-step instability chatter (absl log): SimWorld reports a divergence in one line."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(_MUTED_MESSAGES)


_absl_log = logging.getLogger("absl")
if not any(isinstance(f, _MuteDivergence) for f in _absl_log.filters):
    _absl_log.addFilter(_MuteDivergence())


class SimWorld:
    """Steps the physics on sim time; devices register a pre-step hook (motor controllers)."""

    def __init__(self, model: mujoco.MjModel, hint: str = DEFAULT_HINT) -> None:
        """`hint`: what to change when the physics diverges (SimulationUnstableError's advice)."""
        self.model = model
        self.data = mujoco.MjData(model)
        self.clutches = Clutches(model)
        self.hint = hint
        self._pre_step: list[StepHook] = []
        mujoco.mj_forward(model, self.data)
        self._warning_counts = self.data.warning.number  # a live view: read every step at ~0.3 us
        self._unstable_count = self._unstable_warnings()

    @property
    def timestep_s(self) -> float:
        """Physics step (s)."""
        return float(self.model.opt.timestep)

    @property
    def time_s(self) -> float:
        """Sim time (s)."""
        return float(self.data.time)

    def add_pre_step(self, hook: StepHook) -> None:
        """Run `hook(data)` before every mj_step (e.g. slewing motor set points)."""
        self._pre_step.append(hook)

    def step(self) -> None:
        """One physics step, then the clutches react to the coupling torques it produced;
        SimulationUnstableError if MuJoCo found the state diverging (and reset it)."""
        for hook in self._pre_step:
            hook(self.data)
        t0_s = float(self.data.time)
        mujoco.mj_step(self.model, self.data)
        count = self._unstable_warnings()
        if count != self._unstable_count or not self.data.time > t0_s:
            message = self._diverged(t0_s, self._unstable_count, count)
            self._unstable_count = count
            raise SimulationUnstableError(message)
        self.clutches.update(self.data)

    def advance_to(self, t_s: float) -> None:
        """Step until sim time reaches t_s (to within half a step)."""
        half = 0.5 * self.timestep_s
        while self.data.time < t_s - half:
            self.step()

    def warnings(self) -> dict[str, int]:
        """MuJoCo warnings raised so far, by name (empty when the run is clean)."""
        return {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(self.data.warning) if w.number}

    def _unstable_warnings(self) -> tuple[int, ...]:
        return tuple(self._warning_counts[_UNSTABLE_INDEX].tolist())

    def _diverged(self, t_s: float, before: tuple[int, ...], after: tuple[int, ...]) -> str:
        """One line: when, what MuJoCo saw, and what to change."""
        seen = [what for what, b, a in zip(UNSTABLE_WARNINGS.values(), before, after, strict=True) if a != b]
        what = f"non-finite or huge {' and '.join(seen)}" if seen else "time stopped advancing"
        return f"the simulation diverged at t = {t_s:.3f} s ({what}; MuJoCo reset the state): {self.hint}"
