"""Replay a recorded run's commands in the twin, open loop, with a candidate foam.

The recorded `command` stream holds every set point as the hand received it, at the time it was
sent; replaying them into the twin reproduces the run exactly when the twin's foam is the run's
(the physics does not read the sensors). Readings come back noise-free, in the recorded units:
finger counts, distal torques (eq. 2's N*m) and fingertip-pad forces (N), at the hand's sample times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from twin.interface.devices import HandCommand
from twin.recording.reader import Run
from twin.sim.foam import FoamParams
from twin.tactile.calibration import active
from twin.tactile.layout import FINGERTIP_PADS, LAYOUT


@dataclass(frozen=True)
class Commands:
    """The part of a run a replay needs: its commands and its hand sample times (up to `until_s`)."""

    t_s: NDArray[np.float64]
    position_counts: NDArray[np.float64]
    max_velocity_counts_s: NDArray[np.float64]
    sample_t_s: NDArray[np.float64]

    @classmethod
    def from_run(cls, run: Run, until_s: float | None = None) -> Commands:
        """Commands and sample times of a recorded run."""
        cmd, hand = run.stream("command"), run.stream("hand")
        end = np.inf if until_s is None else until_s
        c, h = cmd.t_s <= end, hand.t_s <= end
        return cls(
            t_s=cmd.t_s[c].astype(float),
            position_counts=cmd["position_counts"][c].astype(float),
            max_velocity_counts_s=cmd["max_velocity_counts_s"][c].astype(float),
            sample_t_s=hand.t_s[h].astype(float),
        )


@dataclass(frozen=True)
class Replay:
    """Noise-free readings of a replay at the hand's sample times; arrays are (n, 3)."""

    t_s: NDArray[np.float64]
    position_counts: NDArray[np.float64]
    torque_nm: NDArray[np.float64]
    tip_force_n: NDArray[np.float64]


def replay(foam: FoamParams, commands: Commands) -> Replay:
    """Run the commands on a twin holding `foam` and sample it where the run was sampled."""
    from twin.sim.backend import SimBackend

    backend = SimBackend(foam, seed=0)
    backend.connect()
    world, hand, tactile = backend.world, backend.hand, backend.tactile
    assert tactile is not None
    tip = [LAYOUT.taxels_of(p) for p in FINGERTIP_PADS]
    drive = hand._qpos[:3]
    from twin.sim.hand import COUNTS_TO_RAD

    events = sorted(
        [(t, 0, i) for i, t in enumerate(commands.sample_t_s)]
        + [(t, 1, i) for i, t in enumerate(commands.t_s)]
    )
    n = len(commands.sample_t_s)
    position, torque, force = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    try:
        for t, kind, i in events:
            world.advance_to(t)
            if kind == 0:
                position[i] = world.data.qpos[drive] / COUNTS_TO_RAD[:3]
                torque[i] = world.clutches.outer_torque_nm
                per_taxel = tactile.taxel_forces_n()
                per_taxel[~active(per_taxel / LAYOUT.area_m2 / 1e3)] = 0.0  # eq. 6 counts active taxels only
                force[i] = [per_taxel[ids].sum() for ids in tip]
            else:
                hand.command(
                    HandCommand(commands.position_counts[i], float(commands.max_velocity_counts_s[i]))
                )
    finally:
        backend.disconnect()
    return Replay(commands.sample_t_s, position, torque, force)
