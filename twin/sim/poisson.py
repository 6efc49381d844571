"""E and the Poisson ratio read together from two opposite stereo pairs, through the twin (issue 38).

A recorded compress run watched by two pairs on opposite sides of the palm's x gives the grasp's
lateral and axial strains (twin.vision.strain_record); the twin runs the same procedure, cameras and
reader on the described object at the placement the run's cameras measured, over a grid of moduli and
Poisson ratios, and the run's strains are read against the grid (twin.vision.lateral_strain
.read_modulus_and_poisson). One implementation for `twin identify` and benchmarks/nu_from_cameras.py.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from twin.interface.devices import HandCommand, HandReading
from twin.recording import open_run
from twin.sim.foam import FoamParams
from twin.sim.scene import PALM_SURFACE_Z_M
from twin.vision.fusion import VISION
from twin.vision.lateral_strain import StrainReading, read_modulus_and_poisson
from twin.vision.strain_record import (
    TROUGHS,
    StrainObservation,
    observation,
    observe_run,
    opposite_pair_streams,
)

PAIRS = ("lateral", "opposite")
"""The rig: the paper's pair and its mirror through the palm axis (the two gaps along the palm's x)."""
SIM_POISSON = (0.2, 0.275, 0.35)
"""The twin's Poisson ratios a run is read against: twin.sim.modulus POISSON_RANGE's ends and middle."""
JOINT_E_PA = (28e3, 40e3, 57e3)
"""The joint read's default moduli: the benchmark's drawn range's ends and its geometric middle."""
DURATION_S = 8.0
"""Sim time of a twin's run: the grasp is balanced by 2.6-4.5 s on the fast block, a trough follows 2 s
later (twin.vision.strain_record.TROUGHS)."""
REFERENCE_CAVEAT = (
    "the twin's nu, not the material's: read through the fast twin, a foam that bulges as an "
    "FEM does (the faithful block) came out 0.09 low to 0.05 high, its interval holding the truth on 2 of 5 "
    "runs (BENCHMARKS.md, The Poisson ratio's reference)"
)
"""What a read says of itself (benchmarks/nu_reference.py): no reference here covers the grasp."""
Y_CLIP_M = 0.01
"""The y placement read is clipped to this (beyond it the hand grasps another object)."""


def observe_recorded(run_dir: Path | str, foam: FoamParams) -> StrainObservation:
    """The strains of a recorded two-pair compress run of `foam` (its described height)."""
    return observe_run(open_run(run_dir), foam.size_m[2], PALM_SURFACE_Z_M)


def observe(foam: FoamParams, seed: int, duration_s: float = DURATION_S) -> StrainObservation:
    """Run the compress procedure on a twin holding `foam`, watched by PAIRS, and read its strains as a
    recorded run's are read (twin.vision.strain_record.observation, on the fused cloud's vision points
    a run records), but with the cameras read only at rest and at the troughs: ~8x cheaper than
    recording 30 fps, and within ~0.0003 of the recorded run's eps_x (tests/twin/sim/test_poisson.py)."""
    from twin.experiments.compress import PHASES, CompressController
    from twin.rig import Rig
    from twin.sim.backend import SimBackend
    from twin.sim.cameras import PLACEMENTS
    from twin.vision.pipeline import StereoPipeline
    from twin.vision.reconstruct import Rectifier

    backend = SimBackend(foam, seed=seed, stereo=True, stereo_placement=[PLACEMENTS[n] for n in PAIRS])
    backend.connect()
    try:
        pipes = []
        for k, stereo in enumerate(backend.stereo_pairs):
            cal = stereo.calibration()
            pipes.append(StereoPipeline(cal, backend.object_box(Rectifier(cal), pair=k)))
        controller = CompressController()
        period_s = 1.0 / controller.profile.frequency_hz
        rest: list = []
        at_troughs: list = []
        state: dict = {"t_compress": None, "seen": set()}

        def clouds() -> tuple[np.ndarray, np.ndarray]:
            out = []
            for stereo, pipe in zip(backend.stereo_pairs, pipes, strict=True):
                fused = pipe.process(stereo.read()).fused
                out.append(np.asarray(fused.points_hand[fused.source == VISION], dtype=np.float64))
            return out[0], out[1]

        class Watcher:  # the procedure's controller, with the cameras read at rest and at the troughs
            @property
            def phase(self) -> str:
                return controller.phase

            def __call__(self, reading: HandReading) -> HandCommand | None:
                for pipe in pipes:
                    pipe.observe_hand(reading)
                if not rest:
                    rest.append(clouds())
                command = controller(reading)
                if controller.phase == "compress":
                    if state["t_compress"] is None:
                        state["t_compress"] = reading.t_s
                    since_s = reading.t_s - state["t_compress"]
                    k = round(since_s / period_s)
                    on_trough = abs(since_s - k * period_s) < 0.5 / 30.0
                    if on_trough and k < TROUGHS and k not in state["seen"]:
                        state["seen"].add(k)
                        taxels, normals = pipes[0].kinematics.taxels()
                        at_troughs.append((clouds(), taxels, normals))
                return command

        Rig(backend, phases=PHASES).run(Watcher(), duration_s)
        if not at_troughs:
            raise ValueError("the twin's grasp never reached the squeeze")
        return observation(rest[0], at_troughs, foam.size_m[2], PALM_SURFACE_Z_M)
    finally:
        backend.disconnect()


def twin_foam(
    foam: FoamParams, young_pa: float, poisson: float, placement_m: tuple[float, float]
) -> FoamParams:
    """The described object at a modulus, Poisson ratio and placement."""
    return replace(foam, young_pa=young_pa, poisson=poisson, placement_m=placement_m)


def placement_m(run: StrainObservation, foam: FoamParams, young_pa: float, seed: int) -> tuple[float, float]:
    """Where the run's object stood on the palm (x, y; m): x from its two faces at rest; y from the
    clouds' y extents, less their reading on one twin run at y = 0 (the rig's own offset)."""
    x_m = run.centre_x_m
    probe = observe(twin_foam(foam, young_pa, SIM_POISSON[1], (x_m, 0.0)), seed)
    y_m = float(np.clip(run.centre_y_reading_m - probe.centre_y_reading_m, -Y_CLIP_M, Y_CLIP_M))
    return x_m, y_m


def read_joint(
    run: StrainObservation,
    foam: FoamParams,
    seed: int,
    young_pa: Sequence[float] = JOINT_E_PA,
    poisson: Sequence[float] = SIM_POISSON,
) -> tuple[StrainReading, tuple[float, float]]:
    """E and nu together from the run's two strains: the twin at the placement its cameras measured,
    over `young_pa` x `poisson` (one run each, seeds from `seed`), read by read_modulus_and_poisson;
    and the placement (m). len(young_pa) x len(poisson) + 1 simulations of DURATION_S."""
    where = placement_m(run, foam, float(np.exp(np.mean(np.log(young_pa)))), seed)
    reading, _ = _grid_read(run, foam, young_pa, poisson, where, seed + 1)
    return reading, where


def _grid_read(
    run: StrainObservation,
    foam: FoamParams,
    young_pa: Sequence[float],
    poisson: Sequence[float],
    where: tuple[float, float],
    first_seed: int,
) -> tuple[StrainReading, int]:
    """The twin at `where` over `young_pa` x `poisson` (one run each, seeds from `first_seed`), the run's
    two strains read through them (read_modulus_and_poisson); and how many simulations that took."""
    young, nus, strains = [], [], []
    for i, e_pa in enumerate(young_pa):
        for k, nu in enumerate(poisson):
            seen = observe(twin_foam(foam, e_pa, nu, where), first_seed + len(poisson) * i + k)
            young.append(e_pa)
            nus.append(nu)
            strains.append(seen.strains())
    reading = read_modulus_and_poisson(run.strains(), np.array(young), np.array(nus), np.array(strains))
    return reading, len(young)


def young_grid_pa(centre_pa: float, half_width: float = math.log(57 / 28) / 2) -> tuple[float, float, float]:
    """Three moduli centred (geometrically) on `centre_pa`, as wide as JOINT_E_PA (x/÷ 1.43)."""
    return (centre_pa * math.exp(-half_width), centre_pa, centre_pa * math.exp(half_width))


COARSE_E_PA = (15e3, 45e3, 135e3)
"""Moduli of the first, coarse pass (at the middle Poisson ratio), spanning the library's 15-150 kPa: the
grasp's axial strain (its force is set by the balance) places the run's E among them, and the joint
grid is centred there (young_grid_pa)."""
SEED = 38_900
"""The twin's seeds for a run's read (its noise: the twin's frames are noised as a run's are)."""


@dataclass(frozen=True)
class PoissonRead:
    """E and nu of a two-pair run read from its strains through the twin, each with a 95 % interval."""

    poisson: float
    poisson_95: tuple[float, float]
    young_pa: float
    young_95_pa: tuple[float, float]
    placement_m: tuple[float, float]
    strains: tuple[float, float]
    simulations: int

    def poisson_95_simulated(self) -> tuple[tuple[float, float], bool]:
        """nu's 95 % interval within the Poisson ratios the twin simulated (SIM_POISSON's ends), and
        whether the read's own (linearised) interval reached beyond them: where it does, the cameras
        cannot narrow nu on that side (a flat strain-to-nu slope gives intervals like -8 to 8). An interval
        wholly beyond one end is that end (0.38-0.45 reads 0.35-0.35: nu at least the twin's largest)."""
        low, high = SIM_POISSON[0], SIM_POISSON[-1]
        read_low, read_high = self.poisson_95
        beyond = read_low < low or read_high > high
        return (float(np.clip(read_low, low, high)), float(np.clip(read_high, low, high))), beyond

    def to_json(self) -> dict:
        """As the results file records it, with where it came from."""
        within, beyond = self.poisson_95_simulated()
        return {
            "poisson": self.poisson,
            "poisson_ci95": list(within),
            "poisson_ci95_linearised": list(self.poisson_95),
            "poisson_ci95_beyond_simulated": beyond,
            "young_from_strains_pa": self.young_pa,  # not the identification's E (the squeeze's)
            "young_from_strains_ci95_pa": list(self.young_95_pa),
            "placement_m": list(self.placement_m),
            "strains": {"eps_x": self.strains[0], "eps_z": self.strains[1]},
            "simulations": self.simulations,
            "source": "two opposite stereo pairs: the object's width (its two x faces) against its top (the "
            "downward-facing taxels) at rest and at the squeeze's troughs, read through the twin over E x nu "
            "(twin.sim.poisson; interval: the strains' noise, twin.vision.lateral_strain.STRAIN_NOISE, and "
            "the grid fit's residuals, linearised, then cut to the simulated Poisson ratios "
            f"{SIM_POISSON[0]:g}-{SIM_POISSON[-1]:g})",
            "reference": REFERENCE_CAVEAT,
        }


def read_run(run_dir: Path | str, foam: FoamParams, seed: int = SEED) -> PoissonRead:
    """E and nu of a recorded two-pair compress run of the described object `foam` (its shape and size;
    twin.sim.modulus.describe): its strains (observe_recorded); a coarse pass over COARSE_E_PA at the
    middle nu and the placement its cameras measured in x (one of them, the nearest in axial strain,
    also reads the rig's y offset: placement_m); then the joint grid young_grid_pa(E) x SIM_POISSON
    there (read_joint's fit). 12 simulations of DURATION_S. ValueError where the run cannot give the
    strains."""
    run = observe_recorded(run_dir, foam)
    nu_mid = SIM_POISSON[1]
    at_x = (run.centre_x_m, 0.0)
    coarse = [observe(twin_foam(foam, e_pa, nu_mid, at_x), seed + k) for k, e_pa in enumerate(COARSE_E_PA)]
    eps_z = np.array([c.strains()[1] for c in coarse])
    order = np.argsort(eps_z)
    log_e = float(np.interp(run.strains()[1], eps_z[order], np.log(COARSE_E_PA)[order]))
    probe = coarse[int(np.argmin(np.abs(eps_z - run.strains()[1])))]
    y_m = float(np.clip(run.centre_y_reading_m - probe.centre_y_reading_m, -Y_CLIP_M, Y_CLIP_M))
    where = (run.centre_x_m, y_m)
    reading, simulated = _grid_read(run, foam, young_grid_pa(math.exp(log_e)), SIM_POISSON, where, seed + 10)
    return PoissonRead(
        reading.poisson,
        reading.poisson_95,
        reading.young_pa,
        reading.young_95_pa,
        where,
        run.strains(),
        len(coarse) + simulated,
    )


def drawn_poisson_range(
    tolerated: tuple[float, float], measured_95: tuple[float, float]
) -> tuple[tuple[float, float], str | None]:
    """The Poisson ratios the modulus simulations draw once the cameras measured nu: the tolerated range
    cut to the measurement's 95 % interval; where the two do not overlap, the tolerated range, and a
    note saying so."""
    low, high = max(tolerated[0], measured_95[0]), min(tolerated[1], measured_95[1])
    if low <= high:
        return (low, high), None
    return tolerated, (
        f"the cameras' nu {measured_95[0]:.3f}-{measured_95[1]:.3f} lies outside the tolerated "
        f"{tolerated[0]:g}-{tolerated[1]:g}: the tolerated range is drawn"
    )


NO_PAIRS = "the run has no two opposite stereo pairs"


@dataclass(frozen=True)
class PoissonForModulus:
    """What the two pairs give an identification: their read (None where there is none, and `failed` says
    why), the Poisson ratios the modulus simulations draw, and a note where read and tolerance disagree."""

    read: PoissonRead | None
    failed: str | None
    drawn: tuple[float, float]
    note: str | None = None


def poisson_for_modulus(
    run_dir: Path | str,
    description: FoamParams | None,
    tolerated: tuple[float, float],
    *,
    narrow: bool,
    announce: Callable[[str], None] | None = None,
) -> PoissonForModulus:
    """`twin identify`'s use of the cameras, in one place for the CLI and benchmarks/identification_cameras:
    nu read from the run's two opposite pairs (read_run, on the object `description` or the run's own
    record of it); with `narrow` the drawn range is the tolerated one cut to the read's 95 % interval
    (drawn_poisson_range), else the tolerated range. `announce(message)` just before the read's 12
    simulations."""
    from twin.sim.fit import foam_of_run
    from twin.sim.modulus import describe

    run = open_run(run_dir)
    if opposite_pair_streams(run) is None:
        return PoissonForModulus(None, NO_PAIRS, tolerated)
    if announce is not None:
        announce("reading the Poisson ratio from the two stereo pairs (12 simulations)...")
    try:
        read = read_run(run_dir, describe(description if description is not None else foam_of_run(run)))
    except ValueError as exc:
        return PoissonForModulus(None, str(exc), tolerated)
    if not narrow:
        return PoissonForModulus(read, None, tolerated)
    drawn, note = drawn_poisson_range(tolerated, read.poisson_95)
    return PoissonForModulus(read, None, drawn, note)
