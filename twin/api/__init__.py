"""The researcher's Python API: build a backend, run a procedure or your own controller, open the run.

Everything the `twin` command line does goes through these functions, so a script gets the same run
directory (Arrow streams + run.json), the same safety layer between the controller and the hand, the
same Rerun recording and the same one-line errors (`twin.interface.errors.TwinError`). docs/api.md
walks through them. Backends are imported when first asked for: a driver-only install (no `[sim]`
extra) builds a hardware backend without dm_control, and nothing here imports torch.
"""

from __future__ import annotations

import re
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from twin.interface.backend import Backend
from twin.interface.devices import HandCommand, HandReading
from twin.interface.errors import ConfigError, RunWarning
from twin.recording import Run, open_run
from twin.safety import SafetyLayer, SafetyLimits
from twin.session import RunOutcome, default_run_dir
from twin.validation import DAY_S, MIN_DURATION_S, SEED_LIMIT, check_number

if TYPE_CHECKING:
    from twin.experiments.compress import CompressProfile
    from twin.experiments.free_motion import FreeMotionProfile
    from twin.hardware.rig_config import RigConfig
    from twin.shape.model import ShapeModel
    from twin.sim.foam import FoamParams

__all__ = [
    "Backend",
    "ControllerFn",
    "HandCommand",
    "HandReading",
    "Run",
    "RunOutcome",
    "RunWarning",
    "SafetyLimits",
    "compress",
    "foam",
    "free",
    "hardware_backend",
    "library",
    "load_shape_model",
    "open_run",
    "run",
    "sim_backend",
]

Progress = Callable[[float], None]
"""Called with the run clock (s) after every hand reading: drive a progress bar with it."""


class ControllerFn(Protocol):
    """Your controller: the latest hand reading (raw counts) in, set points out (None: keep the last).

    An optional `phase` attribute (a str) names the procedure's present phase; it is recorded with
    every command, as an index into the run's `phases`."""

    def __call__(self, reading: HandReading) -> HandCommand | None: ...


def library() -> dict[str, FoamParams]:
    """The foam library by name (`twin objects`): geometry, material and fidelity of each object."""
    from twin.sim.foam import LIBRARY

    return dict(LIBRARY)


def foam(
    name: str = "block",
    *,
    mesh: str | Path | None = None,
    mesh_scale_m: float = 0.001,
    **overrides: Any,
) -> FoamParams:
    """A foam object: the library's `name`, with any FoamParams field replaced (`young_pa=20e3`,
    `size_m=(0.05, 0.05, 0.05)`, `fidelity="faithful"`; None values are ignored).

    `mesh`: a closed .stl/.obj surface (`mesh_scale_m` metres per file unit) with `name`'s material;
    it is tetrahedralised now, so a bad mesh fails here in one line (ConfigError)."""
    from twin.sim.foam import get_object, mesh_object

    base = get_object(name)
    if mesh is None:
        return base.with_overrides(**overrides)
    if overrides.get("size_m") is not None:
        raise ConfigError("--size-mm does not apply to --object-mesh (the mesh gives the size)")
    from twin.sim.scene import foam_mesh

    result = mesh_object(Path(mesh), base, mesh_scale_m).with_overrides(**overrides)
    foam_mesh(result)
    return result


def sim_backend(
    obj: str | FoamParams | None = "block",
    *,
    seed: int = 0,
    cameras: bool = False,
    render_native: bool = False,
    stereo_calibration: str | Path | None = None,
    camera_placements: str | Sequence[str] | None = None,
) -> Backend:
    """The twin: the hand, its 162 taxels and (with `cameras`) the stereo pair around `obj` (a library
    name, a `foam(...)`, or None for the empty hand), on simulated time; deterministic for a seed.

    `stereo_calibration`: a `twin calibrate cameras` file to reconstruct with (default: the sim's truth;
    the first pair's). `camera_placements`: where the pairs stand, one pair each (twin.sim.cameras
    PLACEMENTS: `lateral`, `opposite`, `top`, or one string `lateral,opposite`; default `lateral`
    alone); a run records every pair."""
    from twin.sim.backend import SimBackend

    check_number(seed, "seed", kind=int, min=0, max=SEED_LIMIT - 1)  # numpy's range, in one line
    params = foam(obj) if isinstance(obj, str) else obj
    placements = None
    if camera_placements is not None:
        from twin.sim.cameras import placements_named

        if not cameras:
            raise ConfigError("camera placements need cameras")
        placements = placements_named(camera_placements)
    return SimBackend(
        params,
        seed=seed,
        stereo=cameras,
        stereo_render_native=render_native,
        stereo_calibration_file=None if stereo_calibration is None else Path(stereo_calibration),
        stereo_placement=placements,
    )


def hardware_backend(
    rig: str | Path | RigConfig | None = None,
    *,
    hand: str | None = None,
    cameras: bool = False,
) -> Backend:
    """The devices of a rig on wall time: `rig` is a rig.toml (ports, baud, limits, calibration files;
    see hardware/README.md) or a loaded RigConfig, `hand` a port or pyserial URL that overrides the
    file's (`/dev/ttyUSB0`, `socket://host:port`, `bh8emu://` for an in-process emulated hand).

    The cameras a rig configures stay closed unless `cameras` is set."""
    from twin.hardware.backend import HardwareBackend
    from twin.hardware.rig_config import RigConfig, load_rig

    config = rig if isinstance(rig, RigConfig) else RigConfig() if rig is None else load_rig(Path(rig))
    if hand is not None:
        config = config.with_hand_port(hand)
    backend = HardwareBackend(config)
    if cameras and backend.stereo is None:
        raise ConfigError("--cameras: the rig has no cameras (add a [stereo] section to rig.toml)")
    if not cameras:
        backend.stereo = None  # configured but not asked for: the run leaves them closed
    return backend


def load_shape_model(path: str | Path, object_name: str | None = None) -> ShapeModel:
    """A `twin train` contour model to predict the object's outline live (`compress(shape_model=)`);
    refused in one line if it is a surface model or was trained on another object than `object_name`."""
    from twin.shape.model import ShapeModel

    try:
        model = ShapeModel.load(Path(path))
    except ValueError as exc:
        raise ConfigError(f"--predict {exc}") from None
    if model.target == "surface":
        raise ConfigError("--predict: a surface model (--target surface); live prediction takes contours")
    trained_on = model.metadata.get("object")
    if object_name is not None and trained_on and trained_on != object_name:
        raise ConfigError(
            f"--predict: the model was trained on '{trained_on}', the hand holds '{object_name}'"
        )
    return model


class _Procedure:
    """A plain callable as the rig's controller: its `phase` (or the run's first phase), and a clear
    error when it returns something that is not a HandCommand."""

    def __init__(self, fn: ControllerFn, default_phase: str) -> None:
        self._fn = fn
        self._default = default_phase

    @property
    def phase(self) -> str:
        """The controller's own phase where it keeps one."""
        phase = getattr(self._fn, "phase", None)
        return phase if isinstance(phase, str) else self._default

    def __call__(self, reading: HandReading) -> HandCommand | None:
        command = self._fn(reading)
        if command is not None and not isinstance(command, HandCommand):
            raise ConfigError(f"the controller returned {type(command).__name__}, not a HandCommand or None")
        return command


def _object_name(backend: Backend, given: str | None) -> str:
    """What is in the hand: the caller's word, else the sim's foam ('none': empty), else 'unnamed'."""
    if given is not None:
        return given
    if hasattr(backend, "foam"):
        return "none" if backend.foam is None else backend.foam.name
    return "unnamed"


def _out_dir(out: str | Path | None, experiment: str, object_name: str) -> Path:
    """`out`, or runs/EXPERIMENT-OBJECT-TIMESTAMP: both names must be plain (no path of their own)."""
    if out is not None:
        return Path(out)
    for what, value in (("name", experiment), ("object_name", object_name)):
        if not isinstance(value, str) or not _PLAIN_NAME.fullmatch(value):
            raise ConfigError(
                f"{what} {value!r:.60}: letters, digits, '.', '_' and '-' only (it names the run directory)"
            )
    return default_run_dir(experiment, object_name)


_PLAIN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")
"""A name that may become part of a run directory's name: never a path, never hidden."""


def _warn_completed(outcome: RunOutcome) -> RunOutcome:
    """Each of a complete run's warnings (twin.session.completion_warnings) as a RunWarning at the
    caller's line: a hardware loop at half its rate must not pass silently. Returns `outcome`."""
    from twin.session import completion_warnings

    for line in completion_warnings(outcome):
        warnings.warn(line, RunWarning, stacklevel=3)  # 1: here, 2: twin.run/compress/free, 3: the caller
    return outcome


def _check_duration(duration_s: object) -> float:
    """A run length as the CLI takes it (finite, at least 1 ms, at most a day), before anything exists."""
    return float(check_number(duration_s, "duration_s", min=MIN_DURATION_S, max=DAY_S))


def run(
    backend: Backend,
    controller: ControllerFn,
    *,
    duration_s: float,
    out: str | Path | None = None,
    name: str = "custom",
    phases: tuple[str, ...] | None = None,
    object_name: str | None = None,
    parameters: Mapping[str, Any] | None = None,
    safety: SafetyLimits | None = None,
    progress: Progress | None = None,
) -> RunOutcome:
    """Run your controller on `backend` for `duration_s` (run clock), recorded to `out` (default
    runs/NAME-OBJECT-TIMESTAMP) with run.json, every stream and a Rerun recording, as `twin run` does.

    Every command passes the safety layer (`safety`, default: the rig's limits or the datasheet's)
    before it reaches the hand; an unsafe one stops the run with the hand idled. `phases`: the names
    the controller's `phase` takes (default: its present phase, or `name`). `parameters` go into
    run.json's experiment record. Bad input raises ConfigError (a TwinError) before anything is written."""
    if not callable(controller):
        raise ConfigError(f"the controller must be callable (HandReading -> HandCommand), got {controller!r}")
    duration_s = _check_duration(duration_s)
    from twin.session import run_experiment

    first = getattr(controller, "phase", None)
    if phases is None:
        phases = (first if isinstance(first, str) else name,)
    what = _object_name(backend, object_name)
    experiment: dict[str, Any] = {"name": name, "object": what}
    if parameters:
        experiment["parameters"] = dict(parameters)
    outcome = run_experiment(
        backend=backend,
        controller=_Procedure(controller, phases[0]),
        phases=tuple(phases),
        duration_s=duration_s,
        run_dir=_out_dir(out, name, what),
        experiment=experiment,
        progress=progress,
        argv=list(sys.argv),
        safety=None if safety is None else SafetyLayer(safety),
    )
    return _warn_completed(outcome)


def compress(
    backend: Backend,
    *,
    duration_s: float = 10.0,
    out: str | Path | None = None,
    object_name: str | None = None,
    profile: CompressProfile | None = None,
    stereo_box: tuple[int, int, int, int] | None = None,
    shape_model: ShapeModel | None = None,
    progress: Progress | None = None,
    argv: list[str] | None = None,
) -> RunOutcome:
    """The paper's procedure (§6.2): grasp, balance the grasp forces, then compress periodically
    (`twin run compress`). `stereo_box`: the object's box on the first frame where the backend has
    cameras (default: the sim's own, or rig.toml's bbox); `shape_model`: see `load_shape_model`."""
    from twin.experiments.compress import run_compress

    duration_s = _check_duration(duration_s)
    what = _object_name(backend, object_name)
    outcome = run_compress(
        backend,
        _out_dir(out, "compress", what),
        duration_s=duration_s,
        object_name=what,
        profile=profile,
        progress=progress,
        argv=argv if argv is not None else list(sys.argv),
        stereo_box=stereo_box,
        shape_model=shape_model,
    )
    return _warn_completed(outcome)


def free(
    backend: Backend,
    *,
    duration_s: float = 20.0,
    out: str | Path | None = None,
    profile: FreeMotionProfile | None = None,
    progress: Progress | None = None,
    argv: list[str] | None = None,
) -> RunOutcome:
    """The empty hand swings its fingers (`twin run free`): the run `twin identify --free` takes for
    eq. 4's hand terms."""
    from twin.experiments.free_motion import run_free_motion

    duration_s = _check_duration(duration_s)
    outcome = run_free_motion(
        backend,
        _out_dir(out, "free", "none"),
        duration_s=duration_s,
        profile=profile,
        progress=progress,
        argv=argv if argv is not None else list(sys.argv),
    )
    return _warn_completed(outcome)
