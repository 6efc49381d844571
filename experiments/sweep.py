"""Dataset sweeps for the shape network (paper §7): many compression runs with varied finger
trajectories, run in parallel on this machine (processes) or on a Ray cluster, resumable and seeded.

Each job grasps the object like `compress` (close, balance), then drives every finger with its own
sine: amplitude, frequency and phase drawn per finger from the job's seed, so the network sees the
fingers move together and apart. At each 30 Hz hand sample it keeps the finger positions (counts),
the distal torques (eq. 2) and the object's contours in the left camera (twin.vision.contour: the
largest visible piece's outline and the hull of all pieces), the inputs and the targets of the
paper's network. With `surface` it also runs the run's stereo pipeline (reconstruction and tactile
fill-in) and keeps the fused cloud as a height map on a fixed hand-frame grid (twin.shape.surface),
with the twin's true surface on the same grid: the targets of the 3-D variant.

A job drives the twin directly rather than through the rig: it records only the dataset's arrays, and
no safety layer stands between it and the simulated hand (its set points stay within the compress
procedure's 400-count limit by construction). Hardware data comes from recorded runs instead.

A dataset directory holds one .npz per trajectory (written to a temporary name, then renamed, so a
killed sweep never leaves a half file) and index.json listing them; a rerun skips every trajectory
whose file exists. The same seeds give the same files whichever executor ran them.
"""

from __future__ import annotations

import json
import math
import os
import socket
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from twin.experiments.compress import CompressController, CompressProfile

from twin.interface.errors import ConfigError

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from twin.interface.devices import HandReading
    from twin.sim.backend import SimBackend
    from twin.vision.contour import Contour

INDEX_FILE = "index.json"
EXECUTORS = ("local", "ray")
AMPLITUDE_COUNTS = (50.0, 200.0)
"""Each finger presses from its balanced grasp by 0 to 2 amplitudes: at most 400 counts, the compress
procedure's own limit (offset + amplitude)."""
FREQUENCY_HZ = (0.2, 0.8)
RAMP_S = 1.0
"""The waves fade in over the first second of the compression, so every finger starts at its grasp."""
SURFACE_ERODE_PX = 6
"""The surface sweep's stereo pipeline shrinks the object's mask by this much: block matching smears
the fingers' disparity this far into the object's edge, and the smeared points sit at the finger's
depth, ~35 mm under the block's top. On a squeezed block, the heights' mean error against the true
top was 12 mm with no erosion, 5.8 mm with 2 px, 0.4 mm with 4 px; since the grasp changed (issue 6:
the fingers sit nearer the top rim), 2.0 / 0.28 / 0.20 mm with 4 / 5 / 6 px on block trajectory 6
(49 / 6 / 0 of ~900 (sample, cell) pairs more than 5 mm off; trajectory 8 alike), at the cost of 17 ->
12 cells seen per frame."""


@dataclass(frozen=True)
class Trajectory:
    """One job: an object, its per-finger waves, a noise seed and a length."""

    object_name: str
    index: int
    seed: int
    duration_s: float
    amplitude_counts: tuple[float, float, float]
    frequency_hz: tuple[float, float, float]
    phase_rad: tuple[float, float, float]
    points: int
    surface: bool = False
    """Also keep the fused 3-D surface (stereo pipeline + tactile fill-in): about twice the cost."""

    @property
    def name(self) -> str:
        """File stem: object and index."""
        return f"{self.object_name}-{self.index:04d}"


def draw_trajectories(
    objects: Iterable[str], count: int, seed: int, duration_s: float, points: int, surface: bool = False
) -> list[Trajectory]:
    """`count` trajectories per object, each drawn from its own stream of `seed` (reproducible, and
    independent of how many are drawn)."""
    out = []
    for obj in objects:
        for i in range(count):
            rng = np.random.default_rng([seed, i, sum(map(ord, obj))])
            out.append(
                Trajectory(
                    object_name=obj,
                    index=i,
                    seed=int(rng.integers(2**31)),
                    duration_s=duration_s,
                    amplitude_counts=tuple(float(a) for a in rng.uniform(*AMPLITUDE_COUNTS, 3)),
                    frequency_hz=tuple(float(f) for f in rng.uniform(*FREQUENCY_HZ, 3)),
                    phase_rad=tuple(float(p) for p in rng.uniform(0, 2 * math.pi, 3)),
                    points=points,
                    surface=surface,
                )
            )
    return out


class TrajectoryController(CompressController):
    """Close and balance as `compress`; then each finger follows its own wave from the grasp."""

    def __init__(self, trajectory: Trajectory) -> None:
        super().__init__(CompressProfile(envelope=False))  # its own waves, not the compress wave's scaling
        self.trajectory = trajectory

    def _compress(
        self, t_s: float, position: np.ndarray | None = None, torque: np.ndarray | None = None
    ) -> np.ndarray:
        """Each finger's own wave, ramped in over RAMP_S (it needs no reading)."""
        tr = self.trajectory
        t = t_s - self._t_phase
        a, f, ph = (np.asarray(x) for x in (tr.amplitude_counts, tr.frequency_hz, tr.phase_rad))
        wave = a * (1 + np.sin(2 * np.pi * f * t + ph)) * min(1.0, t / RAMP_S)
        return self.grasp_counts + wave


def run_trajectory(trajectory: Trajectory, out_dir: str) -> dict:
    """One job on the twin: its samples to <out_dir>/<name>.npz; returns its index entry."""
    from twin.interface.errors import SimulationUnstableError

    try:
        return _run_trajectory(trajectory, out_dir)
    except SimulationUnstableError as exc:  # name the job: the sweep runs many
        raise SimulationUnstableError(f"trajectory {trajectory.name}: {exc}") from None


def _run_trajectory(trajectory: Trajectory, out_dir: str) -> dict:
    os.environ.setdefault("MUJOCO_GL", "egl")
    from twin.sim.backend import SimBackend
    from twin.sim.cameras import LEFT_CAMERA
    from twin.sim.foam import get_object
    from twin.units import strain_to_torque_nm
    from twin.vision.contour import ContourError, ContourExtractor, view_from_hand
    from twin.vision.reconstruct import Rectifier

    path = Path(out_dir) / f"{trajectory.name}.npz"
    foam = get_object(trajectory.object_name)
    backend = SimBackend(foam, seed=trajectory.seed, stereo=True, tactile=trajectory.surface)
    backend.connect()
    try:
        rectifier = Rectifier(backend.stereo.calibration())
        box = backend.object_box(rectifier)
        world, hand, stereo = backend.world, backend.hand, backend.stereo
        surface = _SimSurface(backend, box) if trajectory.surface else None
        first = surface.first_left() if surface else stereo.read_view(LEFT_CAMERA)
        plane_z = 0.075 + foam.size_m[2] / 2  # the object's mid-height above the palm plate (z = 75 mm)
        extract = ContourExtractor(
            rectifier, rectifier.remap(first), box, points=trajectory.points, plane_z_m=plane_z
        )
        controller = TrajectoryController(trajectory)
        period = hand.spec.period_s
        rows = _new_rows(trajectory.surface)
        lost = 0
        for k in range(int(trajectory.duration_s / period) + 1):
            world.advance_to(k * period)
            reading = hand.read()
            hand.command(controller(reading))
            if surface is not None:
                surface.observe(reading)
            if controller.phase != "compress":
                continue
            left = surface.read_left() if surface else stereo.read_view(LEFT_CAMERA)
            try:
                contour = extract(rectifier.remap(left))
            except ContourError:
                lost += 1
                continue
            _append(
                rows,
                reading.t_s,
                reading.position_counts,
                strain_to_torque_nm(reading.strain_counts),
                contour,
            )
            if surface is not None:
                heights, truth = surface.heights()
                rows["surface_mm"].append(heights)
                rows["surface_truth_mm"].append(truth)
        extra = {"view_from_hand": json.dumps(view_from_hand(rectifier).tolist())}
        if surface is not None:
            extra["surface_grid"] = json.dumps(asdict(surface.grid))
    finally:
        backend.disconnect()
    return _entry(trajectory, path, _save(path, rows, trajectory, **extra), lost)


class _SimSurface:
    """The sweep's 3-D targets on the twin: the run's own stereo pipeline (reconstruction, tactile
    fill-in) on every frame, the fused cloud's height map, and the true surface's on the same grid."""

    def __init__(self, backend: SimBackend, box: tuple[int, int, int, int]) -> None:
        import tempfile

        from twin.tactile.calibration import load_calibration
        from twin.vision.pipeline import StereoPipeline

        self.backend = backend
        with tempfile.TemporaryDirectory() as tmp:
            self.tactile_calibration = load_calibration(backend.write_calibration(Path(tmp)))
        self.pipeline = StereoPipeline(backend.stereo.calibration(), box, erode_px=SURFACE_ERODE_PX)
        self.grid = None
        self._frame = None

    def observe(self, reading: HandReading) -> None:
        """Follow the hand's pose and the pads' pressures (what the pipeline's fill-in needs)."""
        self.pipeline.observe_hand(reading)
        scan = self.backend.tactile.read()
        self.pipeline.observe_tactile(self.tactile_calibration.to_kpa(scan.counts))

    def first_left(self) -> NDArray[np.uint8]:
        """The object at rest: lay the grid on its fused cloud; its left view starts the contour tracker."""
        from twin.shape.surface import grid_from_cloud
        from twin.vision.contour import view_from_hand

        frame = self.backend.stereo.read()
        view = view_from_hand(self.pipeline.rectifier)
        self.grid = grid_from_cloud(self.pipeline.process(frame).fused.points_hand, view_from_hand=view)
        return frame.left

    def read_left(self) -> NDArray[np.uint8]:
        """A stereo pair now; its left view for the contour, the pair kept for `heights`."""
        self._frame = self.backend.stereo.read()
        return self._frame.left

    def heights(self) -> tuple[np.ndarray, np.ndarray]:
        """The last pair's fused cloud and the true surface now, as heights on the grid (mm)."""
        from twin.shape.surface import height_map, mesh_heights
        from twin.sim.surface_truth import true_surface

        fused = self.pipeline.process(self._frame).fused
        world = self.backend.world
        truth = mesh_heights(true_surface(world.model, world.data), self.grid)
        return height_map(fused.points_hand, self.grid), truth


def trajectory_from_run(run_dir: Path | str, out_dir: Path, points: int = 32) -> dict:
    """A recorded run with cameras (sim or hardware) as one dataset trajectory: its recorded left frames
    through the same contour code, each paired with the hand reading delivered at or before it.

    The run gets the next free index of its object (the same one again when it is added twice).
    The frames are rectified with the run's own stereo calibration; the tracker starts from the box
    the run recorded on its first frame. Contours in mm need the object's height (the run's object
    description); without it they are NaN and only pixel errors can be scored."""
    from twin.recording.reader import Run
    from twin.shape.surface import grid_from_cloud, height_map
    from twin.vision.calibration import StereoCalibration
    from twin.vision.contour import ContourError, ContourExtractor, view_from_hand
    from twin.vision.pipeline import decode_jpeg
    from twin.vision.reconstruct import Rectifier

    run = Run(run_dir)
    for stream in ("hand", "stereo"):
        if stream not in run.streams or not len(run.stream(stream)):
            raise ConfigError(f"{run.path}: no '{stream}' stream; record the run with --cameras")
    calibration_file = (run.metadata.get("calibration_files") or {}).get("stereo_calibration")
    if calibration_file is None:
        raise ConfigError(f"{run.path}: the run kept no stereo calibration")
    rectifier = Rectifier(StereoCalibration.load(run.path / calibration_file))
    stereo, hand = run.stream("stereo"), run.stream("hand")
    obj = run.metadata.get("object") or {}
    plane_z = 0.075 + obj["size_m"][2] / 2 if obj.get("size_m") else None
    phases = tuple(run.metadata.get("phases", ()))
    in_compress = np.ones(len(hand), dtype=bool)
    if "compress" in phases and "command" in run.streams:
        cmd = run.stream("command")
        at = np.clip(np.searchsorted(cmd.t_s, hand.t_s, side="right") - 1, 0, len(cmd) - 1)
        in_compress = cmd["phase"][at] == phases.index("compress")
    first = rectifier.remap(decode_jpeg(stereo["left_jpeg"][0]))
    box = tuple(int(v) for v in stereo["box"][0])
    extract = ContourExtractor(rectifier, first, box, points=points, plane_z_m=plane_z)
    rows = _new_rows(surface=True)
    del rows["surface_truth_mm"]  # a recorded run knows no true surface
    try:  # the grid on the first frame's fused cloud; without one, the run gives contours only
        first_cloud = np.asarray(stereo["points_m"][0]).reshape(-1, 3)
        grid = grid_from_cloud(first_cloud, view_from_hand=view_from_hand(rectifier))
    except ConfigError:
        grid = None
        del rows["surface_mm"]
    lost = 0
    for t, jpeg, cloud in zip(stereo.t_s, stereo["left_jpeg"], stereo["points_m"], strict=True):
        left = rectifier.remap(decode_jpeg(jpeg))
        try:
            contour = extract(left)  # every frame, so the tracker follows the object
        except ContourError:
            lost += 1
            continue
        i = int(np.searchsorted(hand.t_s, t, side="right")) - 1
        if i < 0 or not in_compress[i]:
            continue
        _append(rows, float(t), hand["position_counts"][i, :3], hand["torque_nm"][i], contour)
        if grid is not None:
            rows["surface_mm"].append(height_map(np.asarray(cloud).reshape(-1, 3), grid))
    object_name = run.metadata.get("experiment", {}).get("object") or obj.get("name") or "object"
    existing = [e for e in read_index(out_dir) if e["object_name"] == object_name]
    same_run = [e["index"] for e in existing if e.get("run") == str(run.path)]
    index = same_run[0] if same_run else 1 + max((e["index"] for e in existing), default=-1)
    trajectory = Trajectory(
        object_name=object_name,
        index=index,
        seed=int(run.metadata.get("seed") or 0),
        duration_s=float(run.metadata.get("duration_s") or 0.0),
        amplitude_counts=(0.0, 0.0, 0.0),
        frequency_hz=(0.0, 0.0, 0.0),
        phase_rad=(0.0, 0.0, 0.0),
        points=points,
        surface=grid is not None,
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{trajectory.name}.npz"
    extra = {"view_from_hand": json.dumps(view_from_hand(rectifier).tolist())}
    if grid is not None:
        extra["surface_grid"] = json.dumps(asdict(grid))
    saved = _save(path, rows, trajectory, run=str(run.path), **extra)
    entry = _entry(trajectory, path, saved, lost) | {"run": str(run.path)}
    index_entries = {e["file"]: e for e in read_index(out_dir)} | {entry["file"]: entry}
    _write_index(out_dir, index_entries)
    return entry


CONTOUR_COLUMNS = ("contour_px", "contour_mm", "hull_px", "hull_mm")
"""The largest visible piece's outline and the hull of all pieces, in px and in hand-frame mm."""
SURFACE_COLUMNS = ("surface_mm", "surface_truth_mm")
"""Heights (mm) of the fused cloud and of the twin's true surface on the trajectory's grid."""


def _new_rows(surface: bool = False) -> dict[str, list]:
    """Per-sample lists of a trajectory file's arrays."""
    keys = ("t_s", "position_counts", "torque_nm", *CONTOUR_COLUMNS, *(SURFACE_COLUMNS if surface else ()))
    return {k: [] for k in keys}


def _append(
    rows: dict[str, list], t_s: float, counts: np.ndarray, torque_nm: np.ndarray, contour: Contour
) -> None:
    """One sample's inputs and contours (mm columns NaN when the contour has no plane)."""
    rows["t_s"].append(t_s)
    rows["position_counts"].append(np.asarray(counts, dtype=float)[:3])
    rows["torque_nm"].append(np.asarray(torque_nm, dtype=float))
    nan = np.full_like(contour.pixels, np.nan)
    rows["contour_px"].append(contour.pixels)
    rows["contour_mm"].append(nan if contour.hand_mm is None else contour.hand_mm)
    rows["hull_px"].append(contour.hull_pixels)
    rows["hull_mm"].append(nan if contour.hull_mm is None else contour.hull_mm)


def _save(path: Path, rows: dict[str, list], trajectory: Trajectory, **extra: str) -> int:
    """Write a trajectory file whole (temporary name, then rename); returns its sample count."""
    arrays = {k: np.asarray(v, dtype=np.float64) for k, v in rows.items()}
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **arrays, trajectory=json.dumps(asdict(trajectory)), **extra)
    tmp.replace(path)
    return len(arrays["t_s"])


def _entry(trajectory: Trajectory, path: Path, samples: int, lost: int) -> dict:
    entry = {"file": path.name, "samples": samples, "lost_frames": lost, **asdict(trajectory)}
    return json.loads(json.dumps(entry))  # as the index stores it (tuples become lists)


def sweep(
    trajectories: list[Trajectory],
    out_dir: Path,
    *,
    workers: int = 2,
    executor: str = "local",
    address: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[dict]:
    """Run every trajectory not already in out_dir; write and return the dataset index."""
    if executor not in EXECUTORS:
        raise ConfigError(f"unknown executor '{executor}' (choose from {', '.join(EXECUTORS)})")
    if workers < 1:
        raise ConfigError("--workers must be >= 1")
    if executor == "ray" and address is not None:
        check_ray_address(address)
    out_dir.mkdir(parents=True, exist_ok=True)
    index = {e["file"]: e for e in read_index(out_dir)}
    todo = [t for t in trajectories if not (out_dir / f"{t.name}.npz").exists()]
    done = len(trajectories) - len(todo)
    if progress is not None:
        progress(done, len(trajectories))
    runner = _run_local if executor == "local" else _run_ray
    for entry in runner(todo, out_dir, workers, address):
        index[entry["file"]] = entry
        done += 1
        _write_index(out_dir, index)
        if progress is not None:
            progress(done, len(trajectories))
    for t in trajectories:  # finished before this call but missing from the index (a killed sweep)
        if f"{t.name}.npz" not in index:
            with np.load(out_dir / f"{t.name}.npz") as data:
                index[f"{t.name}.npz"] = _entry(t, out_dir / f"{t.name}.npz", len(data["t_s"]), 0)
    _write_index(out_dir, index)
    return [index[f"{t.name}.npz"] for t in trajectories]


def _run_local(todo: list[Trajectory], out_dir: Path, workers: int, address: str | None) -> Iterable[dict]:
    if address is not None:
        raise ConfigError("--address is for --executor ray")
    if workers == 1:
        for t in todo:
            yield run_trajectory(t, str(out_dir))
        return
    from concurrent.futures import as_completed

    from twin.processes import worker_pool

    # spawned workers (a parent that has rendered holds an EGL context a forked child would deadlock
    # on) that die with this process; an error or Ctrl-C cancels the rest and ends them
    with worker_pool(workers) as pool:
        futures = [pool.submit(run_trajectory, t, str(out_dir)) for t in todo]
        for f in as_completed(futures):
            yield f.result()


RAY_PROBE_TIMEOUT_S = 5.0
"""How long the cluster's head gets to accept a connection before `--address` is refused: ray.init
itself retries a dead address silently for minutes."""


def check_ray_address(address: str) -> None:
    """ConfigError unless `address` (host:port or ray://host:port; 'auto' passes) accepts a TCP connection."""
    if address == "auto":
        return
    where = address.removeprefix("ray://")
    host, _, port = where.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"--address {address!r}: expected host:port, ray://host:port or auto")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=RAY_PROBE_TIMEOUT_S).close()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ConfigError(
            f"--address {address}: no Ray cluster answers there ({reason} within {RAY_PROBE_TIMEOUT_S:g} s)"
        ) from None


def _run_ray(todo: list[Trajectory], out_dir: Path, workers: int, address: str | None) -> Iterable[dict]:
    try:
        import ray
    except ImportError:
        raise ConfigError("--executor ray needs Ray: pip install 'barrett-twin[cluster]'") from None
    started = not ray.is_initialized()
    if started:
        if address is None:  # a local instance with this many workers
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    try:
        remote = ray.remote(num_cpus=1)(run_trajectory)
        pending = [remote.remote(t, str(out_dir.resolve())) for t in todo]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])
    finally:
        if started:
            ray.shutdown()


def read_index(out_dir: Path) -> list[dict]:
    """The dataset's index entries (empty for a new directory)."""
    path = Path(out_dir) / INDEX_FILE
    if not path.exists():
        return []
    try:
        return json.loads(path.read_text())["trajectories"]
    except (ValueError, KeyError) as exc:
        raise ConfigError(f"{path}: not a readable dataset index ({exc})") from None


def _write_index(out_dir: Path, index: dict[str, dict]) -> None:
    path = out_dir / INDEX_FILE
    tmp = path.with_suffix(".tmp")
    entries = sorted(index.values(), key=lambda e: (e["object_name"], e["index"]))
    tmp.write_text(
        json.dumps({"format": "barrett-twin shape dataset", "version": 1, "trajectories": entries}, indent=1)
    )
    tmp.replace(path)
