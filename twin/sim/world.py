"""One MuJoCo world: model, data, the clutches, and the hooks devices run around every step."""

from __future__ import annotations

from collections.abc import Callable

import mujoco

from twin.sim.clutch import Clutches

StepHook = Callable[[mujoco.MjData], None]


class SimWorld:
    """Steps the physics on sim time; devices register a pre-step hook (motor controllers)."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.clutches = Clutches(model)
        self._pre_step: list[StepHook] = []
        mujoco.mj_forward(model, self.data)

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
        """One physics step, then the clutches react to the coupling torques it produced."""
        for hook in self._pre_step:
            hook(self.data)
        mujoco.mj_step(self.model, self.data)
        self.clutches.update(self.data)

    def advance_to(self, t_s: float) -> None:
        """Step until sim time reaches t_s (to within half a step)."""
        half = 0.5 * self.timestep_s
        while self.data.time < t_s - half:
            self.step()

    def warnings(self) -> dict[str, int]:
        """MuJoCo warnings raised so far, by name (empty when the run is clean)."""
        return {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(self.data.warning) if w.number}
