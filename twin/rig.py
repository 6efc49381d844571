"""The rig: one session, one clock, multi-rate sampling, the safety layer, recording and visualization.

The rig schedules each device at its declared rate. On sim time a reading sampled at t reaches the
controller and the recording at t + latency (as dm_control's observable delay); on hardware the
latency has already happened on the wire. The rig imports no backend.
"""

from __future__ import annotations

import contextlib
import heapq
import math
import tempfile
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from twin import units
from twin.interface.backend import Backend, stereo_stream_name
from twin.interface.devices import (
    FINGER_LABELS,
    N_TAXELS,
    HandCommand,
    HandReading,
    StereoFrame,
    TactileReading,
)
from twin.processes import interrupts_deferred
from twin.recording import FieldSpec, RunWriter, StreamSpec
from twin.safety import SafetyLayer, UnsafeCommandError
from twin.tactile.calibration import TaxelCalibration, active_counts, load_calibration, pad_forces_n
from twin.tactile.layout import LAYOUT

if TYPE_CHECKING:
    from twin.shape.model import ShapeModel  # torch: imported only by runs that predict

    # The vision stack (OpenCV, scipy.ndimage, scikit-image) is imported only by runs with cameras.
    from twin.vision.pipeline import HandSnapshot, StereoPipeline, SurfaceFrame


class Controller(Protocol):
    """An experiment procedure: hand reading in, command (or None to keep the last) out."""

    phase: str

    def __call__(self, reading: HandReading) -> HandCommand | None: ...


class SceneViewer(Protocol):
    """What the rig needs of a visualizer (twin.viz.rerun_log.RunRecording fits)."""

    def log_scalars(self, stream: str, t_s: float, values: dict, labels: dict | None = None) -> None: ...


def hand_stream_spec(rate_hz: float, velocity_unit: str) -> StreamSpec:
    """The recorded hand stream: raw readings beside their physical conversion."""
    return StreamSpec(
        name="hand",
        rate_hz=rate_hz,
        description=(
            "BH8 feedback, motors F1, F2, F3, S (raw) and eqs. 1-3 conversion; "
            "t_s: when the reading was taken (on hardware: when the feedback request it answers was sent)"
        ),
        fields={
            "position_counts": FieldSpec(
                unit="counts",
                shape=(4,),
                dtype="int32",
                kind="raw",
                description="motor encoders F1, F2, F3, S",
            ),
            "velocity_counts": FieldSpec(
                unit=velocity_unit,
                shape=(4,),
                dtype="int32",
                kind="raw",
                description="encoder counts per velocity sample time (the unit's time base), F1, F2, F3, S",
            ),
            "strain_counts": FieldSpec(
                unit="counts", shape=(3,), dtype="int32", kind="raw", description="distal strain gauges F1-F3"
            ),
            "position_rad": FieldSpec(
                unit="rad",
                shape=(4,),
                kind="physical",
                description="F1-F3 as inner-link angle, S as spread angle (counts times the §3.1 scale)",
            ),
            "velocity_rad_s": FieldSpec(
                unit="rad/s", shape=(4,), kind="physical", description="eq. 1: rate of position_rad"
            ),
            "torque_nm": FieldSpec(
                unit="N*m", shape=(3,), kind="physical", description="eq. 2: distal-joint torque F1-F3"
            ),
            "force_kg": FieldSpec(
                unit="kg", shape=(3,), kind="physical", description="eq. 3: fingertip force F1-F3"
            ),
        },
    )


def command_stream_spec(rate_hz: float) -> StreamSpec:
    """The recorded commands, as applied after the device's clipping."""
    return StreamSpec(
        name="command",
        rate_hz=rate_hz,
        description=(
            "set points sent to the hand and the procedure phase; "
            "t_s: when the set point was sent, in answer to the hand reading just before it"
        ),
        fields={
            "position_counts": FieldSpec(
                unit="counts", shape=(4,), kind="command", description="set points F1, F2, F3, S"
            ),
            "max_velocity_counts_s": FieldSpec(
                unit="counts/s", kind="command", description="speed limit of the move to the set points"
            ),
            "phase": FieldSpec(
                unit="1", dtype="int32", kind="status", description="index into metadata 'phases'"
            ),
        },
    )


def truth_stream_spec(rate_hz: float) -> StreamSpec:
    """What only a simulator knows, recorded for checking the science against."""
    return StreamSpec(
        name="truth",
        rate_hz=rate_hz,
        description="simulator ground truth at the hand's sample instants",
        fields={
            "inner_rad": FieldSpec(unit="rad", shape=(3,), kind="truth", description="inner joints F1-F3"),
            "outer_rad": FieldSpec(unit="rad", shape=(3,), kind="truth", description="outer joints F1-F3"),
            "spread_rad": FieldSpec(unit="rad", kind="truth", description="spread joint"),
            "distal_torque_nm": FieldSpec(
                unit="N*m", shape=(3,), kind="truth", description="distal-joint torque F1-F3"
            ),
            "broken_away": FieldSpec(
                unit="1", shape=(3,), dtype="bool", kind="truth", description="clutch broken away F1-F3"
            ),
            "tip_contact_force_n": FieldSpec(
                unit="N", shape=(3,), kind="truth", description="contact force on the fingertips F1-F3"
            ),
        },
    )


def tactile_stream_spec(rate_hz: float) -> StreamSpec:
    """The recorded tactile scans: raw counts beside eq. 5 pressures and eq. 6 pad forces."""
    pads = ", ".join(LAYOUT.pad_names)
    return StreamSpec(
        name="tactile",
        rate_hz=rate_hz,
        description=(
            f"PPS pads, 162 taxels in layout id order (twin.tactile.layout); pads: {pads}; "
            "t_s: when the scan was taken (on hardware: when its frame arrived)"
        ),
        fields={
            "counts": FieldSpec(
                unit="counts",
                shape=(N_TAXELS,),
                dtype="int32",
                kind="raw",
                description="15-bit taxel readings",
            ),
            "sequence": FieldSpec(unit="1", dtype="int64", kind="status", description="device frame number"),
            "dropped_frames": FieldSpec(
                unit="1", dtype="int64", kind="status", description="frames the device dropped so far"
            ),
            "pressure_kpa": FieldSpec(unit="kPa", shape=(N_TAXELS,), kind="physical", description="eq. 5"),
            "pad_force_n": FieldSpec(
                unit="N", shape=(len(LAYOUT.pads),), kind="physical", description="eq. 6"
            ),
            "active_taxels": FieldSpec(
                unit="1",
                shape=(len(LAYOUT.pads),),
                dtype="int32",
                kind="physical",
                description="pressed taxels per pad",
            ),
        },
    )


MAX_STEREO_BACKLOG = 30
"""Frames (1 s at 30 fps) the vision worker may fall behind before the rig waits for it: the pipeline
runs at ~80-110 fps on one core, so only a starved machine gets here."""
STEREO_TRUTH_EVERY = 3
"""Score every 3rd stereo frame against the truth (10 Hz at 30 fps): the segmentation render it
needs costs ~3-5 ms of the main thread per frame."""
STEREO_TRUTH_FIELDS = ("median_mm", "p90_mm", "coverage", "outside_fraction", "visible_px")


def stereo_truth_stream_spec(rate_hz: float) -> StreamSpec:
    """Each stereo frame's reconstruction scored against the twin's true foam surface."""
    return StreamSpec(
        name="stereo_truth",
        rate_hz=rate_hz,
        description="reconstruction vs the true foam surface at the frame's instant (twin.sim.surface_truth)",
        fields={
            "median_mm": FieldSpec(unit="mm", kind="truth", description="median point-to-surface distance"),
            "p90_mm": FieldSpec(unit="mm", kind="truth", description="90th percentile of the same"),
            "coverage": FieldSpec(unit="1", kind="truth", description="visible foam pixels with a point"),
            "outside_fraction": FieldSpec(unit="1", kind="truth", description="points off the foam"),
            "visible_px": FieldSpec(unit="px", dtype="int32", kind="truth", description="foam pixels seen"),
        },
    )


def contour_stream_spec(name: str, rate_hz: float, points: int, what: str) -> StreamSpec:
    """A contour per sample: the shape network's prediction or the camera's measurement (rectified px)."""
    return StreamSpec(
        name=name,
        rate_hz=rate_hz,
        description=f"the object's contour, {what} (rectified left camera, {points} points from the top)",
        fields={
            "contour_px": FieldSpec(
                unit="px", dtype="float32", kind="physical", shape=(points, 2), description=f"{what} contour"
            )
        },
    )


def summarize_surface_scores(scores: list[dict], median_mm: float = 1.5, coverage: float = 0.6) -> dict:
    """A run's reconstruction accuracy over its stereo frames (what run.json and `twin info` report)."""
    med = np.array([s["median_mm"] for s in scores], dtype=float)
    cov = np.array([s["coverage"] for s in scores], dtype=float)
    ok = (med <= median_mm) & (cov >= coverage)
    return {
        "frames": len(scores),
        "median_mm": float(np.nanmedian(med)),
        "worst_median_mm": float(np.nanmax(med)),
        "p90_mm": float(np.nanmedian([s["p90_mm"] for s in scores])),
        "coverage": float(np.median(cov)),
        "worst_coverage": float(np.min(cov)),
        "frames_within_targets": float(np.mean(ok)),
        "targets": {"median_mm": median_mm, "coverage": coverage},
    }


_Event = tuple[float, int, str, object]
"""(time s, order pushed, kind, payload): the rig's schedule is a heap of these plain tuples, ordered by
time, then by the order they were pushed (never by kind or payload: the order is unique)."""


LOOP_RATE_TOLERANCE = 0.98
"""A hardware hand loop below 98 % of its declared rate is reported (RigResult.warnings)."""
CLIP_TOLERANCE_COUNTS = 0.5
"""A finger's set point sent more than half a count (the encoder's resolution) from the one the procedure
asked for was clipped: by the safety layer (held at the force cap) or by the hand (its range)."""


@dataclass
class RigResult:
    """How a run went: samples delivered per stream, the final phase, and what needs saying."""

    samples: dict[str, int]
    final_phase: str
    duration_s: float
    warnings: list[str] = field(default_factory=list)
    """One line each, e.g. a hardware hand loop that missed its declared rate; the run still completed."""


@dataclass
class StopReport:
    """Why a run stopped early and what the rig verified after: whether the hand acknowledged its idle."""

    reason: str
    """The stopping error, one line (or "interrupted (Ctrl-C or SIGTERM)")."""
    error_type: str
    idle: str
    """'acknowledged' (the hand took its idle command), 'failed' (it did not answer: it may still be
    powered) or 'not connected' (its connection was already gone: not idled)."""
    idle_error: str | None = None

    @property
    def hand_safe(self) -> bool:
        """True when the hand acknowledged its idle."""
        return self.idle == "acknowledged"

    def message(self) -> str:
        """One line for run.json's error and the CLI: the stop, then what became of the hand."""
        if self.idle == "acknowledged":
            after = "the hand was idled"
        elif self.idle == "failed":
            after = f"idling the hand failed: {self.idle_error}; the hand may still be powered"
        else:
            after = "the hand's connection was already closed, so it was not idled; it may still be powered"
        return f"{self.reason}; {after}"

    def to_json(self) -> dict:
        """For run.json's metadata ('stop')."""
        return {
            "reason": self.reason,
            "error_type": self.error_type,
            "idle": self.idle,
            "idle_error": self.idle_error,
        }


def _describe(exc: BaseException) -> str:
    """The one line a stopping error stands for."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted (Ctrl-C or SIGTERM)"
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


class Rig:
    """Runs a controller against a backend for a duration, recording every stream."""

    def __init__(
        self,
        backend: Backend,
        writer: RunWriter | None = None,
        viewer: SceneViewer | None = None,
        scene_logger: Callable[[float], None] | None = None,
        scene_rate_hz: float = 30.0,
        phases: tuple[str, ...] = ("idle",),
        safety: SafetyLayer | None = None,
        tactile_calibration: TaxelCalibration | None = None,
        stereo_pipeline: StereoPipeline | Sequence[StereoPipeline] | None = None,
        shape_model: ShapeModel | None = None,
    ) -> None:
        """`stereo_pipeline`: the first pair's pipeline, or one per pair of the backend's
        named_stereo_pairs (in order: each pair is sampled and recorded, stereo_stream_name)."""
        self.backend = backend
        self.shape_model = shape_model
        """Predicts the object's contour from every hand reading (paper §7); None: no prediction."""
        pipelines = [] if stereo_pipeline is None else [stereo_pipeline]
        if isinstance(stereo_pipeline, Sequence):
            pipelines = list(stereo_pipeline)
        pairs = backend.named_stereo_pairs()
        if len(pipelines) > len(pairs):
            raise ValueError(f"{len(pipelines)} stereo pipelines for the backend's {len(pairs)} pair(s)")
        self.stereo_pipelines: list[StereoPipeline] = pipelines
        """One per sampled pair (reconstruction + tactile fill-in), the first pair's first; the backend's
        further pairs without one are not sampled."""
        self.stereo_pipeline = pipelines[0] if pipelines else None
        """The first pair's (the `stereo` stream, its truth scores, contour and viewer); None: cameras not
        sampled."""
        self._stereo_streams = [
            (stereo_stream_name(k, name), name, camera)
            for k, ((name, camera), _) in enumerate(zip(pairs, pipelines, strict=False))
        ]
        """(stream, placement, camera) of each sampled pair."""
        if backend.tactile is not None and tactile_calibration is None:
            with tempfile.TemporaryDirectory() as tmp:  # the backend's files, read as any run reads them
                tactile_calibration = load_calibration(backend.write_calibration(Path(tmp)))
        self.tactile_calibration = tactile_calibration
        self.safety = safety or SafetyLayer()
        self.writer = writer
        self.viewer = viewer
        self.scene_logger = scene_logger
        self.scene_rate_hz = scene_rate_hz
        self.phases = phases
        self._queue: list[_Event] = []
        self._order = 0
        self.samples: dict[str, int] = {}
        self._stereo_sampled = 0
        self.stop: StopReport | None = None
        """Why the run stopped early and what the rig verified after (run.json's 'stop'); None: it did
        not stop early."""
        self._vision: ThreadPoolExecutor | None = None
        self._stereo_jobs: deque[Future] = deque()
        self.surface_scores: list[dict] = []
        self.force_cap_samples = np.zeros(3, dtype=int)
        """Hand readings at which each finger sat at the safety layer's fingertip-force cap (F1-F3)..."""
        self.force_cap_entries = np.zeros(3, dtype=int)
        """...and how many times it reached it: a run that rides the cap says so in run.json."""
        self._at_cap = np.zeros(3, dtype=bool)
        """Per stereo frame, the reconstruction scored against the twin's truth (sim only)."""
        self._clipped = np.zeros(3, dtype=bool)
        """Fingers whose last command was clipped (the viewer's lanes mark where that starts and ends)."""
        self._recovered = False
        self._behind = False
        """The last hand reading came after a recovered cycle / over a period behind its schedule."""
        self.hand_loop_behind: list[tuple[float, float]] = []
        """Hardware: each stretch of hand readings over one period behind the schedule, as (the run time
        it started, s; the most it lagged, s): where readings and the commands answering them came late."""
        self._recoveries_seen = len(backend.hand.recoveries)
        """The hand's recovered cycles already marked (a read's or a command's: at the next reading)."""
        self._frames_dropped = 0
        self._frames_lost = False
        """The pads' frames lost so far (the device's count), and whether the last scan followed a loss."""
        self._velocity_sample_time_s = backend.hand.config.velocity_sample_time_s
        if writer is not None:  # declared together: one rewrite of run.json
            writer.add_streams(*self._stream_specs())

    def _stream_specs(self) -> list[StreamSpec]:
        """The streams this rig records, from its backend's devices and the rig's options."""
        backend, shape_model, stereo_pipeline = self.backend, self.shape_model, self.stereo_pipeline
        hand_spec = backend.hand.spec
        specs = [
            hand_stream_spec(hand_spec.rate_hz, hand_spec.channels["velocity_counts"].unit),
            command_stream_spec(hand_spec.rate_hz),
        ]
        if backend.ground_truth() is not None:
            specs.append(truth_stream_spec(hand_spec.rate_hz))
        if backend.tactile is not None:
            specs.append(tactile_stream_spec(backend.tactile.spec.rate_hz))
        if shape_model is not None:
            specs.append(contour_stream_spec("shape", hand_spec.rate_hz, shape_model.points, "predicted"))
            if stereo_pipeline is not None:
                rate = backend.stereo.spec.rate_hz
                specs.append(contour_stream_spec("contour", rate, shape_model.points, "measured"))
        if stereo_pipeline is not None:
            from twin.vision.pipeline import stereo_stream_spec

            several = len(self._stereo_streams) > 1
            for stream, name, camera in self._stereo_streams:
                specs.append(stereo_stream_spec(camera.spec.rate_hz, stream, name if several else None))
            if backend.ground_truth() is not None:
                rate = backend.stereo.spec.rate_hz / STEREO_TRUTH_EVERY
                specs.append(stereo_truth_stream_spec(rate))
        return specs

    def _push(self, t_s: float, kind: str, payload: object = None) -> None:
        self._order += 1
        heapq.heappush(self._queue, (t_s, self._order, kind, payload))

    def run(
        self,
        controller: Controller,
        duration_s: float,
        progress: Callable[[float], None] | None = None,
    ) -> RigResult:
        """Sample, deliver and control until duration_s on the run clock."""
        clock = self.backend.clock
        clock.start()
        hand = self.backend.hand
        period = hand.spec.period_s
        latency = hand.spec.latency_s if self.backend.is_simulated else 0.0
        n_hand = math.floor(duration_s * hand.spec.rate_hz + 1e-9)
        for k in range(n_hand + 1):
            self._push(k * period, "sample_hand")
        tactile = self.backend.tactile
        if tactile is not None:
            n_tactile = math.floor(duration_s * tactile.spec.rate_hz + 1e-9)
            tactile_latency = tactile.spec.latency_s if self.backend.is_simulated else 0.0
            for k in range(n_tactile + 1):
                self._push(k * tactile.spec.period_s, "sample_tactile")
        stereo = self.backend.stereo if self.stereo_pipeline is not None else None
        stereo_pairs = [camera for _, _, camera in self._stereo_streams]
        if stereo is not None:
            n_stereo = math.floor(duration_s * stereo.spec.rate_hz + 1e-9)
            stereo_latency = stereo.spec.latency_s if self.backend.is_simulated else 0.0
            for k in range(n_stereo + 1):
                self._push(k * stereo.spec.period_s, "sample_stereo")
        if self.scene_logger is not None:
            n_scene = math.floor(duration_s * self.scene_rate_hz + 1e-9)
            for k in range(n_scene + 1):
                self._push(k / self.scene_rate_hz, "scene")
        # Only samples up to duration_s are scheduled; their deliveries (latency later) all complete.
        hand_wall_s: list[float] = []  # wall time of the first and the latest hand sample (hardware)
        try:
            while self._queue:
                event_t_s, _, kind, payload = heapq.heappop(self._queue)
                clock.advance_to(event_t_s)
                if kind == "sample_hand":
                    if not self.backend.is_simulated:
                        now_s = time.monotonic()
                        hand_wall_s = [hand_wall_s[0] if hand_wall_s else now_s, now_s]
                    reading = hand.read()
                    if not self.backend.is_simulated:
                        recovered = list(hand.recoveries[self._recoveries_seen :])
                        self._recoveries_seen += len(recovered)
                        self._note_hand_cycle(reading.t_s, event_t_s, recovered, period)
                    truth = self.backend.ground_truth()
                    if self.backend.is_simulated:
                        self._push(reading.t_s + latency, "deliver_hand", (reading, truth))
                    else:  # the latency has happened on the wire: the controller answers this reading
                        # now, before any later sample a late loop still owes (one clock, no backlog)
                        self._deliver(reading, truth, controller)
                        if progress is not None:
                            progress(event_t_s)
                elif kind == "deliver_hand":
                    reading, truth = payload
                    self._deliver(reading, truth, controller)
                    if progress is not None:
                        progress(event_t_s)
                elif kind == "sample_tactile":
                    for scan in tactile.read_pending():
                        self._push(max(scan.t_s + tactile_latency, event_t_s), "deliver_tactile", scan)
                elif kind == "deliver_tactile":
                    self._deliver_tactile(payload)
                elif kind == "sample_stereo":  # every pair at once (hardware-triggered together)
                    for pair, camera in enumerate(stereo_pairs):
                        pending = camera.read_async()  # the sim renders it while the physics runs on
                        truth = (  # the first pair's frames are scored against the truth
                            self.backend.surface_truth(self.stereo_pipeline.rectifier)
                            if pair == 0 and self._stereo_sampled % STEREO_TRUTH_EVERY == 0
                            else None
                        )
                        self._push(event_t_s + stereo_latency, "deliver_stereo", (pair, pending, truth))
                    self._stereo_sampled += 1
                elif kind == "deliver_stereo":
                    self._deliver_stereo(payload)
                elif kind == "scene":
                    self.scene_logger(event_t_s)
            self._record_stereo(wait=True)
        except BaseException as exc:  # watchdog, device error, unsafe command, Ctrl-C: idle first
            self.stop = self._safe_stop(exc)
            with contextlib.suppress(Exception):  # the stop on the viewer's time axis, where it happened
                state = "command refused" if isinstance(exc, UnsafeCommandError) else "stopped"
                self._event(clock.now(), "run", state, f"run stopped: {self.stop.message()}", "ERROR")
            with contextlib.suppress(Exception):  # keep the frames already taken (<= the backlog)
                self._record_stereo(wait=True)
            raise
        finally:
            if self._vision is not None:
                self._vision.shutdown(wait=True, cancel_futures=True)
                self._vision = None
        warnings = self._loop_rate_warnings(n_hand, duration_s, hand_wall_s)
        return RigResult(dict(self.samples), controller.phase, duration_s, warnings)

    @property
    def stop_reason(self) -> str | None:
        """Why the run stopped early and what became of the hand, one line (None: it did not)."""
        return None if self.stop is None else self.stop.message()

    def _loop_rate_warnings(self, n_hand: int, duration_s: float, wall_s: list[float]) -> list[str]:
        """A hardware hand loop that ran below LOOP_RATE_TOLERANCE of its declared rate, in one line."""
        if self.backend.is_simulated or n_hand < 1 or len(wall_s) < 2 or wall_s[1] <= wall_s[0]:
            return []
        declared_hz = self.backend.hand.spec.rate_hz
        took_s = wall_s[1] - wall_s[0]
        achieved_hz = n_hand / took_s
        if achieved_hz >= LOOP_RATE_TOLERANCE * declared_hz:
            return []
        run_s = n_hand / declared_hz
        return [
            f"hand loop ran at {achieved_hz:.1f} Hz of {declared_hz:g} Hz "
            f"({run_s:.3g} s of run time took {took_s:.3g} s): the readings are further apart than declared"
        ]

    def _event(
        self, t_s: float, lane: str, state: str | None, text: str | None = None, level: str = "WARN"
    ) -> None:
        """A state on one of the viewer's event lanes from t_s on (None ends it), and a log row."""
        log_event = getattr(self.viewer, "log_event", None)
        if log_event is not None:
            log_event(t_s, lane, state, text, level)

    def _note_clipping(self, t_s: float, asked: HandCommand, applied: HandCommand) -> None:
        """Mark where each finger's command starts and stops being clipped (the safety layer holding it
        at the force cap, or the hand's range): the curves show the clipped motion, this says why."""
        want, sent = asked.position_counts[:3], applied.position_counts[:3]
        clipped = np.abs(want - sent) > CLIP_TOLERANCE_COUNTS
        for k in np.flatnonzero(clipped != self._clipped):
            lane = f"{FINGER_LABELS[k]}_command"
            if not clipped[k]:
                self._event(t_s, lane, None)
                continue
            why = (
                f"held by the safety layer at the {self.safety.limits.max_fingertip_force_kg:g} kg force cap"
                if self._at_cap[k]
                else "clipped to the hand's range"
            )
            text = (
                f"{FINGER_LABELS[k]} command clipped: {want[k]:.0f} counts asked, {sent[k]:.0f} sent ({why})"
            )
            self._event(t_s, lane, "clipped", text)
        self._clipped = clipped

    def _note_hand_cycle(
        self, t_s: float, scheduled_s: float, recoveries: list[str], period_s: float
    ) -> None:
        """Hardware: the cycles recovered since the last reading (in this read or the command before it),
        marked at this reading; a loop over one period behind its schedule (k periods from the start);
        each marked where it starts and ends."""
        if recoveries:
            lines = "; ".join(recoveries)
            self._event(t_s, "hand_cycle", "recovered", f"hand cycle recovered ({len(recoveries)}): {lines}")
        elif self._recovered:
            self._event(t_s, "hand_cycle", None)
        self._recovered = bool(recoveries)
        late_s = t_s - scheduled_s
        behind = late_s > period_s
        if behind and not self._behind:
            rate = 1.0 / period_s
            text = f"hand loop {1e3 * late_s:.0f} ms behind its {rate:g} Hz schedule: readings are late"
            self._event(t_s, "hand_loop", f"behind its {rate:g} Hz schedule", text)
            self.hand_loop_behind.append((t_s, late_s))
        elif behind:
            start_s, most_s = self.hand_loop_behind[-1]
            self.hand_loop_behind[-1] = (start_s, max(most_s, late_s))
        elif self._behind and not behind:
            self._event(t_s, "hand_loop", None)
        self._behind = behind

    def _note_lost_frames(self, scan: TactileReading) -> None:
        """The pads' frames lost on the way before a scan (its device counts them: sequence gaps, bad
        frames), marked at that scan on the viewer's tactile_frames lane, cleared at the next one."""
        lost = scan.dropped_frames - self._frames_dropped
        self._frames_dropped = max(self._frames_dropped, scan.dropped_frames)
        if lost > 0:
            text = f"tactile: {lost} frame(s) lost before this scan, {scan.dropped_frames} so far"
            self._event(scan.t_s, "tactile_frames", "frames lost", text)
        elif self._frames_lost:
            self._event(scan.t_s, "tactile_frames", None)
        self._frames_lost = lost > 0

    def _safe_stop(self, exc: BaseException) -> StopReport:
        """Idle the hand (T on hardware) before anything else, and say whether it acknowledged."""
        report = StopReport(_describe(exc), type(exc).__name__, "not connected")
        hand = self.backend.hand
        if not hand.is_connected:
            return report
        try:
            with interrupts_deferred():  # a second Ctrl-C waits until the hand has its idle
                hand.idle()
        except Exception as idle_exc:
            report.idle, report.idle_error = "failed", _describe(idle_exc)
        else:
            report.idle = "acknowledged"
        return report

    def _deliver(self, reading: HandReading, truth: dict | None, controller: Controller) -> None:
        physical = units.hand_reading_to_physical(
            reading.position_counts,
            reading.velocity_counts,
            reading.strain_counts,
            self._velocity_sample_time_s,
        )
        row = {
            "position_counts": reading.position_counts,
            "velocity_counts": reading.velocity_counts,
            "strain_counts": reading.strain_counts,
            **physical,
        }
        self._record("hand", reading.t_s, row)
        for pipeline in self.stereo_pipelines:
            pipeline.observe_hand(reading)
        if truth is not None:
            self._record("truth", reading.t_s, truth)
            log_truth = getattr(self.viewer, "log_truth", None)
            if log_truth is not None:
                log_truth(reading.t_s, truth)
        self.safety.observe(reading)
        at_cap = self.safety.at_force_limit
        self.force_cap_samples += at_cap
        self.force_cap_entries += at_cap & ~self._at_cap
        self._at_cap = at_cap
        if self.shape_model is not None:
            inputs = np.concatenate([reading.position_counts[:3], physical["torque_nm"]])
            predicted = self.shape_model.predict(inputs)
            self._record("shape", reading.t_s, {"contour_px": predicted})
            log_contour = getattr(self.viewer, "log_contour", None)
            if log_contour is not None:
                log_contour(reading.t_s, "predicted", predicted)
        command = controller(reading)
        if command is not None:
            checked = self.safety.check(command)
            # stamped as it goes out, not after: on hardware command() waits for the hand's
            # acknowledgement, a round trip a loaded host stretches (the sim's clock stands still here)
            sent_s = self.backend.clock.now()
            applied = self.backend.hand.command(checked)
            self._note_clipping(sent_s, command, applied)
            self._record(
                "command",
                sent_s,  # on delivery: on hardware at once, in the sim one latency after the sample
                {
                    "position_counts": applied.position_counts,
                    "max_velocity_counts_s": applied.max_velocity_counts_s,
                    "phase": self.phases.index(controller.phase) if controller.phase in self.phases else -1,
                },
            )
            log_command = getattr(self.viewer, "log_command", None)
            if log_command is not None:
                log_command(sent_s, applied.position_counts, controller.phase)
        if self.viewer is not None:
            log_hand = getattr(self.viewer, "log_hand", None)
            if log_hand is not None:
                log_hand(reading.t_s, reading.position_counts, reading.strain_counts, physical)
            else:
                self.viewer.log_scalars(
                    "hand",
                    reading.t_s,
                    {"position_counts": reading.position_counts[:3], "torque_nm": physical["torque_nm"]},
                    labels={"position_counts": FINGER_LABELS, "torque_nm": FINGER_LABELS},
                )

    def _deliver_tactile(self, scan: TactileReading) -> None:
        self._note_lost_frames(scan)
        pressure = self.tactile_calibration.to_kpa(scan.counts)
        forces = pad_forces_n(pressure)
        self._record(
            "tactile",
            scan.t_s,
            {
                "counts": scan.counts,
                "sequence": scan.sequence,
                "dropped_frames": scan.dropped_frames,
                "pressure_kpa": pressure,
                "pad_force_n": forces,
                "active_taxels": active_counts(pressure),
            },
        )
        for pipeline in self.stereo_pipelines:
            pipeline.observe_tactile(pressure)
        log_tactile = getattr(self.viewer, "log_tactile", None)
        if log_tactile is not None:
            log_tactile(scan.t_s, pressure, forces)

    def _deliver_stereo(self, payload: tuple[int, Future[StereoFrame], object]) -> None:
        """Hand the pair to the vision worker (it runs beside the physics); record what it finished."""
        pair, pending, truth = payload
        pipeline = self.stereo_pipelines[pair]
        if self._vision is None:
            self._vision = ThreadPoolExecutor(1, thread_name_prefix="vision")
        self._record_stereo(wait=False)
        while len(self._stereo_jobs) >= MAX_STEREO_BACKLOG:  # a starved worker: bound the memory
            self._record_stereo_oldest()
        # The worker waits for the pair itself: the rig never stalls on a frame still being rendered.
        job = self._vision.submit(self._process_frame, pair, pending, pipeline.hand_snapshot(), truth)
        self._stereo_jobs.append(job)

    def _process_frame(
        self, pair: int, pending: Future[StereoFrame], hand: HandSnapshot, truth: object
    ) -> tuple[int, StereoFrame, SurfaceFrame, dict | None, np.ndarray | None]:
        """On the vision worker: take the pair, reconstruct and fuse, score against the truth if known,
        and (the first pair) trace the measured contour when a shape model predicts one."""
        frame = pending.result()
        surface = self.stereo_pipelines[pair].process(frame, hand)
        r = surface.reconstruction
        score = self.backend.score_surface(truth, r.points_hand, r.pixels)
        measured = self._measured_contour(frame, surface) if pair == 0 else None
        return pair, frame, surface, score, measured

    def _measured_contour(self, frame: StereoFrame, surface: SurfaceFrame) -> np.ndarray | None:
        """The camera's contour of this frame, traced as the model's training targets were: the
        sub-pixel boundary of the tracker's likelihood (twin.vision.contour), the model's target."""
        model, pipeline = self.shape_model, self.stereo_pipeline
        if model is None or pipeline.tracker is None or not surface.reconstruction.mask.any():
            return None
        from twin.vision.contour import ContourError, hull, outlines, resample

        left_rect = pipeline.rectifier.remap(frame.left, "left")
        try:
            pieces = outlines(surface.reconstruction.mask, pipeline.tracker.back_project(left_rect))
            return resample(hull(pieces) if model.target == "hull" else pieces[0], model.points)
        except ContourError:
            return None

    def _record_stereo(self, wait: bool) -> None:
        """Record finished frames in order (all of them when `wait`); a worker's error is raised here."""
        while self._stereo_jobs and (wait or self._stereo_jobs[0].done()):
            self._record_stereo_oldest()

    def _record_stereo_oldest(self) -> None:
        pair, frame, surface, score, measured = self._stereo_jobs.popleft().result()
        if pair > 0:  # a further pair: its stream only (the viewer shows the first)
            self._record(self._stereo_streams[pair][0], frame.t_s, surface.record())
            return
        errors = None if score is None else score.pop("point_error_mm", None)  # for the viewer only
        self._record_surface(frame, surface, measured, errors)
        if score is not None:
            self.surface_scores.append(score)
            self._record("stereo_truth", frame.t_s, {k: score[k] for k in STEREO_TRUTH_FIELDS})
            if self.viewer is not None:
                error = {k: score[k] for k in ("median_mm", "p90_mm") if k in score}
                self.viewer.log_scalars("stereo_truth", frame.t_s, error)

    def _record_surface(
        self,
        frame: StereoFrame,
        surface: SurfaceFrame,
        measured: np.ndarray | None,
        point_error_mm: np.ndarray | None = None,
    ) -> None:
        self._record("stereo", frame.t_s, surface.record())
        if measured is not None:
            self._record("contour", frame.t_s, {"contour_px": measured})
            log_contour = getattr(self.viewer, "log_contour", None)
            if log_contour is not None:
                log_contour(frame.t_s, "measured", measured)
        log_stereo = getattr(self.viewer, "log_stereo", None)
        if log_stereo is not None:
            log_stereo(
                frame.t_s,
                frame.left,
                frame.right,
                reconstruction=surface.reconstruction,
                fused_points_hand=surface.fused.points_hand,
                fused_triangles=surface.fused.triangles,
                tactile_points_hand=surface.tactile_points_hand,
                cloud_stride=3,  # a ninth of the stereo points in the viewer; the stream keeps all
                point_error_mm=point_error_mm,
            )

    def _record(self, stream: str, t_s: float, values: dict) -> None:
        self.samples[stream] = self.samples.get(stream, 0) + 1
        if self.writer is not None:  # the writer checks and copies each value as its declared dtype
            self.writer.append(stream, t_s, values)
