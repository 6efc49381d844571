"""One experiment run end to end: validate, connect, record, visualize, close.

Everything that can be checked is checked before any device is touched or the run directory created:
every file the run reads (tactile and stereo calibration) is loaded from the backend's copies first,
so a bad file leaves nothing behind and the hand unmoved. Once the directory exists, run.json says
whether the run completed, failed or was interrupted, and for a stop why and whether the hand
acknowledged its idle, so nothing half-written looks complete and no status claims more than was
verified.
"""

from __future__ import annotations

import contextlib
import json
import platform
import sys
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from twin import __version__, units
from twin.interface.backend import Backend, stereo_calibration_key
from twin.interface.errors import ConfigError, DeviceError, RunDirectoryLostError, TwinError
from twin.processes import interrupts_deferred
from twin.recording import RunWriter
from twin.rig import Rig, RigResult, summarize_surface_scores
from twin.safety import SafetyLayer
from twin.tactile.calibration import TaxelCalibration, load_calibration

if TYPE_CHECKING:  # the vision stack is imported only by runs with cameras
    from twin.vision.pipeline import StereoPipeline

RRD_NAME = "run.rrd"


@dataclass
class RunOutcome:
    """Where the run went and how it ended."""

    run_dir: Path
    rrd_path: Path
    result: RigResult
    status: str
    warnings: list[str] = field(default_factory=list)
    """Lines to show the user (stderr) beside a complete status, also kept in run.json's 'warnings'."""


def completion_warnings(outcome: RunOutcome) -> list[str]:
    """What a complete run should tell its user, one line each: its warnings (a hardware loop that
    missed its rate) and the hand cycles the driver recovered (run.json lists each one)."""
    lines = list(outcome.warnings)
    try:
        metadata = json.loads((outcome.run_dir / "run.json").read_text())["metadata"]
    except (OSError, ValueError, KeyError, TypeError):  # the run's own reader reports a bad run.json
        return lines
    recoveries = metadata.get("hand_recoveries") or []
    if recoveries:
        lines.append(
            f"the hand driver recovered {len(recoveries)} cycle(s) (run.json: metadata.hand_recoveries); "
            f"first: {recoveries[0]}"
        )
    return lines


def default_run_dir(experiment: str, object_name: str) -> Path:
    """runs/<experiment>-<object>-<UTC timestamp>."""
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{experiment}-{object_name}-{stamp}"


def check_output_dir(run_dir: Path) -> None:
    """Fail (one line) unless run_dir can be created fresh, before anything is simulated."""
    if run_dir.exists():
        if not run_dir.is_dir():
            raise ConfigError(f"--out {run_dir}: exists and is not a directory")
        if any(run_dir.iterdir()):
            raise ConfigError(f"--out {run_dir}: directory is not empty; choose a new one")
        parent = run_dir
    else:
        parent = run_dir.parent
        while not parent.exists():
            parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"--out {run_dir}: {parent} is not a directory")
    try:  # os.access says yes to root everywhere; a real probe does not lie
        tempfile.TemporaryDirectory(dir=parent).cleanup()
    except OSError as exc:
        raise ConfigError(f"--out {run_dir}: cannot write in {parent} ({exc.strerror})") from None


def calibration_tables() -> dict[str, Any]:
    """The conversion constants in force for this run (eqs. 1-3 and encoder scales)."""
    return {
        "strain_torque_eq2": {"offset_nm": units.SG_TORQUE_OFFSET_NM, "slope_nm": units.SG_TORQUE_SLOPE_NM},
        "strain_force_eq3": {"offset_kg": units.SG_FORCE_OFFSET_KG, "slope_kg": units.SG_FORCE_SLOPE_KG},
        "finger_full_counts": units.FINGER_FULL_COUNTS,
        "finger_full_inner_rad": units.FINGER_FULL_INNER_RAD,
        "spread_full_counts": units.SPREAD_FULL_COUNTS,
    }


def run_experiment(
    *,
    backend: Backend,
    controller: Any,
    phases: tuple[str, ...],
    duration_s: float,
    run_dir: Path,
    experiment: dict[str, Any],
    progress: Callable[[float], None] | None = None,
    argv: list[str] | None = None,
    safety: SafetyLayer | None = None,
    stereo_box: tuple[int, int, int, int] | None = None,
    shape_model: Any = None,
    viewer: bool = True,
) -> RunOutcome:
    """Connect the backend, run the controller for duration_s, record to run_dir and run.rrd.

    With a stereo camera on the backend every pair is reconstructed and fused with the pads
    (twin.vision.pipeline); `stereo_box` is the object's bounding box on the first frame (x, y, w, h
    in the rectified left view), by default the one the backend suggests (the sim knows its foam).
    `shape_model` (twin.shape.model.ShapeModel) predicts the object's contour from every hand reading;
    with cameras the measured contour is recorded beside it. `viewer=False` writes no run.rrd (nor imports
    Rerun): the twin's own simulations (twin.sim.modulus) read only the run's streams.
    """
    if not duration_s > 0:
        raise ConfigError(f"--duration must be > 0 s, got {duration_s:g}")
    if stereo_box is not None and backend.stereo is not None:
        height, width = backend.stereo.spec.channels["left"].shape[:2]
        x, y, w, h = stereo_box
        if w <= 0 or h <= 0 or x < 0 or y < 0 or x + w > width or y + h > height:
            raise ConfigError(
                f"--bbox {x},{y},{w},{h}: not a non-empty box inside the {width}x{height} image"
            )
    tactile_calibration, stereo_pipelines = _load_run_files(backend, stereo_box)
    stereo_pipeline = stereo_pipelines[0] if stereo_pipelines else None
    if shape_model is not None and stereo_pipeline is not None:
        from twin.vision.contour import view_from_hand

        shape_model.check_view(view_from_hand(stereo_pipeline.rectifier))
    check_output_dir(run_dir)
    if safety is None:  # the rig's own limits where it declares them (rig.toml), else the datasheet's
        safety = SafetyLayer(backend.safety_limits())
    backend.connect()
    with _interrupts_name(run_dir):  # the CLI says what the run directory now holds
        writer: RunWriter | None = None
        rig: Rig | None = None
        result: RigResult | None = None
        try:
            metadata = {
                "software": {"barrett_twin": __version__, "python": platform.python_version()},
                "command_line": argv if argv is not None else sys.argv,
                "experiment": experiment,
                "duration_s": duration_s,
                "phases": list(phases),
                "calibration": calibration_tables(),
                **backend.metadata(),
            }
            rrd_path = run_dir / RRD_NAME
            writer = RunWriter(run_dir, metadata)
            try:
                files = backend.write_calibration(run_dir / "calibration")
                writer.update_metadata(
                    calibration_files={k: str(v.relative_to(run_dir)) for k, v in files.items()}
                )
                recording = None
                if viewer:
                    from twin.viz.rerun_log import RunKind, RunRecording

                    kind = RunKind(
                        experiment=str(experiment.get("name", "compress")),
                        sim=backend.scene() is not None,
                        stereo=stereo_pipeline is not None,
                        predict=shape_model is not None,
                        tactile=backend.tactile is not None,
                        force_cap_kg=safety.limits.max_fingertip_force_kg,
                    )
                    recording = RunRecording(rrd_path, recording_id=run_dir.name, kind=kind)
                try:
                    scene_logger = _scene_logger(backend, recording) if recording is not None else None
                    if stereo_pipeline is not None and recording is not None:
                        log_setup = getattr(recording, "log_stereo_setup", None)
                        if log_setup is not None:
                            log_setup(stereo_pipeline.calibration, backend.hand_pose_in_world())
                    rig = Rig(
                        backend,
                        writer,
                        recording,
                        scene_logger,
                        phases=phases,
                        safety=safety,
                        tactile_calibration=tactile_calibration,
                        stereo_pipeline=stereo_pipelines,
                        shape_model=shape_model,
                    )
                    result = rig.run(controller, duration_s, progress)
                    recoveries = backend.diagnostics().get("hand_recoveries") or []
                    if recording is not None:
                        for line in result.warnings:  # in the viewer's log too, where the run's curves are
                            recording.log_text(duration_s, line, level="WARN")
                        if recoveries:
                            line = (
                                f"the hand driver recovered {len(recoveries)} cycle(s); "
                                f"first: {recoveries[0]}"
                            )
                            recording.log_text(duration_s, line, level="WARN")
                finally:
                    if recording is not None:
                        recording.close()
                for line in result.warnings:
                    writer.warn(line)
            except BaseException as exc:  # what went wrong is kept even when the run failed
                with interrupts_deferred():  # a second Ctrl-C waits until the status is on disk
                    error = _close_failed(writer, exc, rig, backend, result, controller)
                if error is exc:
                    raise
                raise error from exc
            with interrupts_deferred():
                writer.close("complete", metadata=_diagnostics(backend, rig, result, controller))
        except BaseException as exc:  # the run's own error is the one to report, not a second from cleanup
            if writer is not None and not writer.closed:  # interrupted before its status was written
                with interrupts_deferred(), contextlib.suppress(Exception):
                    _close_failed(writer, exc, rig, backend, result)
            try:
                backend.disconnect()
            except Exception as cleanup:
                exc.add_note(f"(then disconnecting the devices failed too: {cleanup})")
            raise
        backend.disconnect()
    return RunOutcome(run_dir, rrd_path, result, "complete", list(result.warnings))


@contextlib.contextmanager
def _interrupts_name(run_dir: Path) -> Iterator[None]:
    """Any Ctrl-C leaving the block carries the run directory: the first, and a second one that lands
    while the devices are released (a fresh KeyboardInterrupt, raised inside the cleanup), so the CLI
    always reads back what run.json holds."""
    try:
        yield
    except KeyboardInterrupt as exc:
        exc.run_dir = run_dir
        raise


def _load_run_files(
    backend: Backend, stereo_box: tuple[int, int, int, int] | None
) -> tuple[TaxelCalibration | None, list[StereoPipeline]]:
    """Every file the run reads, loaded and checked from the backend's copies in a scratch directory,
    before any device is touched or the run directory made: a bad table costs one line, nothing else.
    The stereo pipelines: one per pair of the rig (none without cameras)."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            files = backend.write_calibration(Path(tmp))
        except OSError as exc:  # a calibration file named in rig.toml that cannot be read
            name = exc.filename or "a calibration file"
            raise ConfigError(f"{name}: cannot read the calibration file ({exc.strerror or exc})") from None
        try:
            tactile = load_calibration(files) if backend.tactile is not None else None
            stereo = [
                _stereo_pipeline(backend, files, stereo_box if pair == 0 else None, pair, name)
                for pair, (name, _) in enumerate(backend.named_stereo_pairs())
            ]
        except ConfigError as exc:  # name the user's file, not the scratch copy that was read
            raise type(exc)(_source_names(str(exc), files, backend)) from None
    return tactile, stereo


def _source_names(message: str, copies: dict[str, Path], backend: Backend) -> str:
    """`message` with each scratch copy's path replaced by the file it was copied from (rig.toml's)."""
    sources = getattr(getattr(backend, "config", None), "calibration", None) or {}
    for name, copy in copies.items():
        message = message.replace(str(copy), str(sources.get(name, name)))
    return message


def _diagnostics(
    backend: Backend, rig: Rig | None, result: RigResult | None, controller: object = None
) -> dict[str, Any]:
    """What run.json keeps beside the status, whatever it is (written with it by writer.close, in one
    rewrite): the backend's diagnostics, the reconstruction scores, the procedure's own account of its
    squeeze (a controller's `run_metadata`, e.g. the compress amplitude it chose), on hardware where the
    hand loop fell over one period behind its schedule, and a finished run's final phase."""
    items = dict(backend.diagnostics())
    run_metadata = getattr(controller, "run_metadata", None)
    if run_metadata is not None:
        items["squeeze_amplitude"] = run_metadata()
    if rig is not None and rig.surface_scores:
        items["stereo_truth"] = summarize_surface_scores(rig.surface_scores)
    if rig is not None:  # the safety layer's cap shapes the curves where a finger sits at it
        items["force_cap"] = {
            "limit_kg": rig.safety.limits.max_fingertip_force_kg,
            "readings_at_cap": rig.force_cap_samples.tolist(),
            "times_reached": rig.force_cap_entries.tolist(),
            "fingers": ["F1", "F2", "F3"],
        }
    if rig is not None and not backend.is_simulated:  # where a host stall delayed readings and commands
        behind = rig.hand_loop_behind
        items["hand_loop"] = {
            "period_ms": round(1e3 * backend.hand.spec.period_s, 3),
            "times_behind": len(behind),
            "longest_behind_ms": round(1e3 * max((late for _, late in behind), default=0.0), 1),
            "behind_from_s": [round(t_s, 3) for t_s, _ in behind],
        }
    if result is not None:
        items["final_phase"] = result.final_phase
    return items


def _close_failed(
    writer: RunWriter,
    exc: BaseException,
    rig: Rig | None,
    backend: Backend,
    result: RigResult | None,
    controller: object = None,
) -> BaseException:
    """Close the run as failed or interrupted with what was verified; the error to raise.

    run.json's error names the stopping error and whether the hand acknowledged its idle; where it
    did not, the CLI's line says so too (a DeviceError with the same message). The diagnostics and the
    stop report go into the same final run.json."""
    stop = rig.stop if rig is not None else None
    message = stop.message() if stop is not None else (str(exc) or type(exc).__name__)
    try:
        items = _diagnostics(backend, rig, result, controller)
    except Exception as failed:  # the run's own error is the one to report
        exc.add_note(f"(its diagnostics could not be kept: {failed})")
        items = {}
    if stop is not None:
        items["stop"] = stop.to_json()
    status = "interrupted" if isinstance(exc, KeyboardInterrupt) else "failed"
    try:
        writer.close(status, message, metadata=items)
    except RunDirectoryLostError as lost:
        return lost
    if stop is not None and not stop.hand_safe and isinstance(exc, TwinError | OSError):
        return DeviceError(message)
    return exc


def _stereo_pipeline(
    backend: Backend,
    files: dict[str, Path],
    box: tuple[int, int, int, int] | None,
    pair: int = 0,
    name: str = "main",
) -> StereoPipeline:
    """The vision pipeline of the rig's pair `pair` (named `name`) from the calibration copied into the
    run; `box`: the object's on its first frame (None: the backend's)."""
    from twin.vision.calibration import StereoCalibration
    from twin.vision.pipeline import StereoPipeline
    from twin.vision.reconstruct import Rectifier

    path = files.get(stereo_calibration_key(pair, name))
    if path is None:
        raise ConfigError(
            "the stereo cameras need a calibration file: run `twin calibrate cameras` and name it "
            "(--stereo-calibration, or calibration in rig.toml's [stereo])"
        )
    calibration = StereoCalibration.load(path)
    spec = backend.named_stereo_pairs()[pair][1].spec.channels["left"]
    height, width = spec.shape[:2]
    if tuple(calibration.left.image_size) != (width, height):
        raise ConfigError(
            f"{path}: calibrated for {calibration.left.image_size[0]}x{calibration.left.image_size[1]} "
            f"images, the cameras deliver {width}x{height}"
        )
    if box is None:
        box = backend.object_box(Rectifier(calibration), pair=pair)
    if box is None:
        raise ConfigError(
            "the stereo cameras need the object's bounding box on the first frame: --bbox x,y,w,h"
        )
    return StereoPipeline(calibration, box)


def _scene_logger(backend: Backend, recording: Any) -> Callable[[float], None] | None:
    """3-D scene logging where the backend has a MuJoCo scene (the sim); on hardware the hand model."""
    scene = backend.scene()
    if scene is None:  # hardware: the hand's model, posed from its readings by the recording itself
        log_hand_model = getattr(recording, "log_hand_model", None)
        if log_hand_model is not None:
            log_hand_model()
        return None
    model, data = scene
    recording.log_model(model)

    tactile = backend.tactile

    def log(t_s: float) -> None:
        recording.log_scene(t_s, data)
        points = getattr(tactile, "contact_points_m", None)
        if points is not None:  # the sim's pads know where they were pressed
            recording.log_contacts(t_s, points, tactile.contact_forces_n)

    return log
