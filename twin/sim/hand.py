"""The simulated BH8: motor set points slewed like the firmware, readings in hardware units."""

from __future__ import annotations

import mujoco
import numpy as np

from twin import units
from twin.interface.devices import Hand, HandCommand, HandReading
from twin.interface.hand_spec import HandConfig, hand_device_spec
from twin.interface.specs import DeviceSpec
from twin.sim.corruption import corrupt
from twin.sim.world import SimWorld

FINGER_ACTUATORS = ("f1_motor", "f2_motor", "f3_motor")
SPREAD_ACTUATOR = "spread_motor"
MAX_COUNTS = np.array([units.FINGER_MAX_COUNTS] * 3 + [units.SPREAD_FULL_COUNTS], dtype=float)
COUNTS_TO_RAD = np.array([units.INNER_RAD_PER_COUNT] * 3 + [units.SPREAD_RAD_PER_COUNT])


class SimHand(Hand):
    """BH8 hand on a SimWorld. Encoder counts follow the motor (drive joint), as on the real hand."""

    def __init__(self, world: SimWorld, config: HandConfig, rng: np.random.Generator) -> None:
        super().__init__()
        self.world = world
        self.config = config
        self._spec = hand_device_spec(config)
        self._rng = rng
        m = world.model
        self._act = np.array([m.actuator(n).id for n in (*FINGER_ACTUATORS, SPREAD_ACTUATOR)], dtype=int)
        joints = ("f1_drive", "f2_drive", "f3_drive", "f1_spread")
        self._qpos = np.array([m.joint(j).qposadr[0] for j in joints])
        self._dof = np.array([m.joint(j).dofadr[0] for j in joints])
        self._target_rad = np.zeros(4)
        self._slew_rad_s = np.full(4, config.max_velocity_counts_s) * COUNTS_TO_RAD
        self._hold = False
        world.add_pre_step(self._slew)

    @property
    def spec(self) -> DeviceSpec:
        """Declared channels, rate and latency of the hand."""
        return self._spec

    def _connect(self) -> None:
        self._target_rad[:] = self.world.data.qpos[self._qpos]
        self.world.data.ctrl[self._act] = self._target_rad

    def _disconnect(self) -> None:
        self.idle_state()

    def idle_state(self) -> None:
        """Hold the links where they are (what T leaves on a non-back-drivable hand)."""
        self._hold = True
        self._target_rad = self.world.data.qpos[self._qpos].copy()

    def command(self, command: HandCommand) -> HandCommand:
        """Set point in counts, clipped to the firmware range; slewed at the requested velocity."""
        self._require_connection()
        counts = np.clip(command.position_counts, 0.0, MAX_COUNTS)
        velocity = float(np.clip(command.max_velocity_counts_s, 1.0, self.config.max_velocity_counts_s))
        self.drive(counts, np.full(4, velocity))
        return HandCommand(counts, velocity)

    def drive(self, target_counts: np.ndarray, velocity_counts_s: np.ndarray) -> None:
        """Per-motor set points and slew rates (the firmware's motor servos; used by the emulator)."""
        self._require_connection()
        self._target_rad = np.clip(np.asarray(target_counts, dtype=float), 0.0, MAX_COUNTS) * COUNTS_TO_RAD
        velocity = np.clip(
            np.abs(np.asarray(velocity_counts_s, dtype=float)), 0.0, self.config.max_velocity_counts_s
        )
        self._slew_rad_s = velocity * COUNTS_TO_RAD
        self._hold = False

    def motor_setpoint_counts(self) -> np.ndarray:
        """(4,) where each motor's servo is heading now (counts)."""
        return self.world.data.ctrl[self._act] / COUNTS_TO_RAD

    def idle(self) -> None:
        """T: motors stop driving. The BH8's worm drives are not back-drivable, so links hold."""
        self._require_connection()
        self.idle_state()

    def _slew(self, data: mujoco.MjData) -> None:
        """Before every physics step: each motor's set point one step's slew closer to its target."""
        if self._hold:
            return
        ctrl = data.ctrl[self._act]
        step = self._slew_rad_s * self.world.model.opt.timestep
        # np.clip's bounds, written out: np.clip costs ~3 us a call, every 2 ms step
        data.ctrl[self._act] = ctrl + np.minimum(np.maximum(self._target_rad - ctrl, -step), step)

    def read(self) -> HandReading:
        """Encoders, velocity (counts per sample time) and strain gauges (eq. 2 inverse)."""
        self._require_connection()
        data = self.world.data
        ch = self._spec.channels
        position = data.qpos[self._qpos] / COUNTS_TO_RAD
        velocity = data.qvel[self._dof] / COUNTS_TO_RAD * self.config.velocity_sample_time_s
        strain = units.torque_nm_to_strain(self.world.clutches.outer_torque_nm)
        return HandReading(
            t_s=self.world.time_s,
            position_counts=corrupt(position, ch["position_counts"], self._rng),
            velocity_counts=corrupt(velocity, ch["velocity_counts"], self._rng),
            strain_counts=corrupt(strain, ch["strain_counts"], self._rng),
        )
