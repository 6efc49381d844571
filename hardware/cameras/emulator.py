"""The Flea2 stereo pair emulated from the twin: both views rendered from one physics state, served as
two MJPEG-over-HTTP streams that `cv2.VideoCapture(url, cv2.CAP_FFMPEG)` opens like a camera.

Transport: each side is `http://HOST:PORT/left.mjpg` / `.../right.mjpg`, `multipart/x-mixed-replace`
with one JPEG per part (FFMPEG's mpjpeg demuxer). It opens in milliseconds (the demuxer probes one
part) and a grab returns a frame well under a millisecond after it is sent: no probing or buffering
options are needed. Matroska over HTTP, which would carry timestamps, was tried and rejected: FFMPEG
probes ~1.4 s of it on open and those frames stay queued (1.3 s of latency) unless
OPENCV_FFMPEG_CAPTURE_OPTIONS lowers probesize, and OpenCV still reports its timestamps relative to
each connection's first frame, so they could not pair the two streams anyway.

A hardware-triggered pair without timestamps: every frame period (`rate_hz`) the trigger thread copies
the twin's pose state under the twin's lock (mj_getState: time, qpos, mocap; microseconds) and hands
it to the render process, which rebuilds the geometry from it (kinematics, cameras, flex vertices),
renders both views (twin.sim.cameras.SimStereo: native 640x480 area-averaged to 320x240, the declared
sensor noise) and sends them back to be JPEG-encoded.

The renderer is a process of its own, at a lower scheduling priority (`RENDER_NICE`), as the real
cameras are devices of their own: rendering costs ~30 ms of CPU per pair (about a core at 30 fps on
llvmpipe), and on a busy machine the emulated hand must still answer every RealTime cycle within its
deadline. There the cameras drop frames (the next trigger waits for the render in flight) and the
hand does not. The two streams of a host are kept in step by the
server: a connection on one side opened within `PAIR_WINDOW_S` of one on the other side joins its
pair and starts at the same frame, and when a host reads slower than the rate both streams of the
pair skip the same frames (the first side to move on picks the newest frame, the other follows), so
grabbing left then right always returns the two views of one state, and never a stale one queued
behind newer frames for more than about a period.

The render process has its own GL context and its own MjData; it is started with `spawn` (never
forked from a process with running threads and GL state).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import mujoco
import numpy as np
from numpy.typing import NDArray

from twin.interface.devices import StereoFrame
from twin.interface.errors import ConfigError

if TYPE_CHECKING:
    from twin.hardware.bh262.firmware import RealTimeTwin

SIDES = ("left", "right")
BOUNDARY = "twinframe"
DEFAULT_QUALITY = 90
"""JPEG quality: ~14 kB per noisy 320x240 view, mean abs error ~1.6 levels (StereoBM is unaffected)."""
PAIR_WINDOW_S = 0.5
"""A connection on one side joins the other side's connection opened less than this long ago."""
HISTORY = 32
"""Frames kept for a pair's slower side (about a second at 30 fps); beyond that the pair is reset."""
SEND_BUFFER = 16_384
"""SO_SNDBUF of a stream (the kernel doubles it): fixed, so a slow host's queue stays a few frames deep."""
STEREO_CALIBRATION_FILE = "stereo_calibration.json"
RENDER_NICE = 10
"""Niceness added to the render process: on a busy machine the cameras yield the CPU to the hand."""
RENDER_START_TIMEOUT_S = 60.0
"""How long the render process may take to start (imports, model, GL context) and render its first pair."""
POSE_STATE = (
    mujoco.mjtState.mjSTATE_TIME
    | mujoco.mjtState.mjSTATE_QPOS
    | mujoco.mjtState.mjSTATE_MOCAP_POS
    | mujoco.mjtState.mjSTATE_MOCAP_QUAT
)
"""What a render needs of the twin's state: everything drawn follows from these by kinematics."""


@dataclass
class EncodedPair:
    """One rendered pair: its number, twin time, when it was published, and both views as JPEG."""

    seq: int
    t_s: float
    published: float
    jpeg: dict[str, bytes]
    frame: StereoFrame


@dataclass
class _Pair:
    """The connections of one host: both sides send the same frames in the same order."""

    created: float
    start: int
    sides: set[str] = field(default_factory=set)
    after: dict[int, int] = field(default_factory=dict)
    """Frame sent after frame k (decided by the first side to move on from k)."""


class _Snapshot:
    """The world-like object SimStereo renders from: the model and a private MjData posed from a state."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)

    @property
    def time_s(self) -> float:
        return float(self.data.time)

    def pose(self, state: NDArray[np.float64]) -> None:
        """Set the POSE_STATE and compute what rendering draws: bodies, cameras, lights, flex vertices."""
        mujoco.mj_setState(self.model, self.data, state, POSE_STATE)
        for stage in (mujoco.mj_kinematics, mujoco.mj_comPos, mujoco.mj_camlight, mujoco.mj_flex):
            stage(self.model, self.data)


def _render_process(model: mujoco.MjModel, config: Any, seed: int, conn: Any, pair: int = 0) -> None:
    """The render process: pose, render and noise one pair (the twin's pair `pair`) per state received,
    until None or EOF.

    Replies ("ready",) once, then ("pair", t_s, left, right, render_s) per state, or ("error", text)."""
    from twin.sim.cameras import SimStereo, pair_camera_names

    with contextlib.suppress(OSError):
        os.nice(RENDER_NICE)
    stereo = None
    try:
        snapshot = _Snapshot(model)
        rng = np.random.default_rng([seed, 3] if pair == 0 else [seed, 3, pair])
        stereo = SimStereo(snapshot, config, rng, cameras=pair_camera_names(pair))  # type: ignore[arg-type]
        stereo.connect()
        conn.send(("ready",))
        while (state := conn.recv()) is not None:
            t0 = time.perf_counter()
            snapshot.pose(state)
            frame = stereo.read()
            conn.send(("pair", frame.t_s, frame.left, frame.right, time.perf_counter() - t0))
    except (EOFError, BrokenPipeError, KeyboardInterrupt):
        pass  # the emulator went away or is stopping
    except BaseException as exc:  # report it: the emulator ends the streams with this message
        with contextlib.suppress(OSError):
            conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        if stereo is not None and stereo.is_connected:
            stereo.disconnect()


class CameraEmulator:
    """One stereo pair of the twin (`pair`: its index in the twin's stereo_pairs) as two MJPEG-over-HTTP
    streams at `rate_hz`."""

    def __init__(
        self,
        twin: RealTimeTwin,
        *,
        pair: int = 0,
        rate_hz: float | None = None,
        quality: int = DEFAULT_QUALITY,
        noise: bool = True,
        seed: int = 0,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        if twin.backend.stereo is None:
            raise ConfigError("the twin has no cameras: build its SimBackend with stereo=True")
        if not 0 <= pair < len(twin.backend.stereo_pairs):
            pairs = len(twin.backend.stereo_pairs)
            raise ConfigError(f"the twin has {pairs} stereo pair(s), not a pair {pair}")
        stereo = twin.backend.stereo_pairs[pair]
        self.pair = pair
        self.name = twin.backend.stereo_placements[pair]
        """Where the pair stands (twin.sim.cameras PLACEMENTS): rig.toml names it so."""
        if rate_hz is not None and not rate_hz > 0:
            raise ConfigError(f"camera emulator rate_hz must be > 0, got {rate_hz}")
        if not 1 <= quality <= 100:
            raise ConfigError(f"camera emulator JPEG quality must be in [1, 100], got {quality}")
        self.twin = twin
        self.config = stereo.config
        self.rate_hz = float(rate_hz or self.config.rate_hz)
        self.quality = int(quality)
        self.noise = noise
        self.seed = seed
        self.on_event = on_event or (lambda _msg: None)
        self.stop_event = threading.Event()
        self.error: BaseException | None = None
        """What stopped the render thread, if it failed (the streams then end)."""
        self.addresses: dict[str, str] = {}
        self.frames = 0
        """Pairs rendered and published."""
        self.sent = dict.fromkeys(SIDES, 0)
        """Frames sent on each side (all connections)."""
        self.render_s: list[float] = []
        self.encode_s: list[float] = []
        self.lock_s: list[float] = []
        """Per pair: pose and render of both views (render process), JPEG encode of both, time the twin's
        lock was held (last 300)."""
        self._cond = threading.Condition()
        self._history: dict[int, EncodedPair] = {}
        self._latest: EncodedPair | None = None
        self._pairs: list[_Pair] = []
        self._server: ThreadingHTTPServer | None = None
        self._threads: list[threading.Thread] = []
        self._ready = threading.Event()

    # --- life cycle -------------------------------------------------------------------------

    def serve_http(self, port: int = 0, host: str = "127.0.0.1") -> tuple[str, str]:
        """Start rendering and listen on host:port (0: a free port); returns the left and right URLs.

        Returns once the first pair is published, so a capture opened next gets a frame at once."""
        if self._server is not None:
            raise RuntimeError("the camera emulator is already serving")
        server = _Server((host, port), _Handler)
        server.emulator = self
        self._server = server
        render = threading.Thread(target=self._render_loop, name="camera-trigger", daemon=True)
        serve = threading.Thread(target=server.serve_forever, args=(0.1,), name="camera-http", daemon=True)
        self._threads = [render, serve]
        render.start()
        serve.start()
        if not self._ready.wait(timeout=RENDER_START_TIMEOUT_S + 5.0) or self.error is not None:
            self.close()
            raise RuntimeError(f"the camera emulator could not render: {self.error}")
        bound = server.server_address[1]
        self.addresses = {side: f"http://{host}:{bound}/{side}.mjpg" for side in SIDES}
        return self.addresses["left"], self.addresses["right"]

    def close(self) -> None:
        """Stop rendering, end every stream and release the port (a capture's next grab fails)."""
        self.stop_event.set()
        with self._cond:
            self._cond.notify_all()
        server, self._server = self._server, None
        if server is not None:
            server.shutdown()
            server.close_connections()
            server.server_close()
        for thread in self._threads:
            thread.join(timeout=2.0)

    def __enter__(self) -> CameraEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def write_calibration(self, directory: Path) -> Path:
        """The twin's ground-truth stereo calibration as a JSON file in `directory` (what a lab's
        calibration would give for these cameras); returns its path."""
        directory.mkdir(parents=True, exist_ok=True)
        with self.twin.lock:
            calibration = self.twin.backend.stereo_pairs[self.pair].calibration()
        name = STEREO_CALIBRATION_FILE if self.pair == 0 else f"stereo_calibration_{self.name}.json"
        return calibration.save(directory / name)

    # --- rendering --------------------------------------------------------------------------

    def _render_loop(self) -> None:
        """The trigger: every period, the twin's pose to the render process and its pair to the streams."""
        world = self.twin.backend.world
        config = self.config if self.noise else _without_noise(self.config)
        context = multiprocessing.get_context("spawn")
        conn, child_conn = context.Pipe()
        args = (world.model, config, self.seed, child_conn, self.pair)
        process = context.Process(target=_render_process, args=args, name="camera-render", daemon=True)
        state = np.empty(mujoco.mj_stateSize(world.model, POSE_STATE))
        try:
            process.start()
            child_conn.close()
            self._receive(conn, process, RENDER_START_TIMEOUT_S)  # ("ready",)
            period = 1.0 / self.rate_hz
            next_t = time.monotonic()
            while not self.stop_event.is_set():
                t0 = time.perf_counter()
                with self.twin.lock:  # only the pose: the render process draws it, the twin steps on
                    mujoco.mj_getState(world.model, world.data, state, POSE_STATE)
                self.lock_s.append(time.perf_counter() - t0)
                conn.send(state)
                reply = self._receive(conn, process, RENDER_START_TIMEOUT_S)
                if reply is None:
                    break
                self._publish(self._encode_pair(*reply[1:]))
                self._ready.set()
                next_t += period
                if next_t < time.monotonic() - period:  # fell behind (a busy host): drop, no burst
                    next_t = time.monotonic()
                if self.stop_event.wait(max(0.0, next_t - time.monotonic())):
                    break
        except BaseException as exc:  # report and end the streams: a host sees the camera stop
            self.error = exc
            self.on_event(f"camera render failed: {exc}")
            self.stop_event.set()
            with self._cond:
                self._cond.notify_all()
        finally:
            self._ready.set()
            with contextlib.suppress(OSError):
                conn.send(None)
            process.join(timeout=5.0)
            if process.is_alive():
                process.terminate()
                process.join(timeout=2.0)
            conn.close()

    def _receive(self, conn: Any, process: Any, timeout_s: float) -> tuple | None:
        """The render process's next reply; None once the emulator is stopping. Raises if it failed,
        died or said nothing for `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        while not conn.poll(0.1):
            if self.stop_event.is_set():
                return None
            if not process.is_alive():
                raise RuntimeError(f"the render process exited (code {process.exitcode})")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the render process gave no frame for {timeout_s:.0f} s")
        reply = conn.recv()
        if reply[0] == "error":
            raise RuntimeError(reply[1])
        return reply

    def _encode_pair(
        self, t_s: float, left: NDArray[np.uint8], right: NDArray[np.uint8], render_s: float
    ) -> EncodedPair:
        t0 = time.perf_counter()
        frame = StereoFrame(t_s=t_s, left=left, right=right)
        jpeg = {side: self.encode(getattr(frame, side)) for side in SIDES}
        self.render_s.append(render_s)
        self.encode_s.append(time.perf_counter() - t0)
        for store in (self.lock_s, self.render_s, self.encode_s):
            del store[:-300]
        return EncodedPair(self.frames + 1, t_s, time.monotonic(), jpeg, frame)

    def encode(self, rgb: NDArray[np.uint8]) -> bytes:
        """One view as JPEG at the emulator's quality."""
        params = [cv2.IMWRITE_JPEG_QUALITY, self.quality]
        ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params)
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        return data.tobytes()

    def _publish(self, pair: EncodedPair) -> None:
        with self._cond:
            self.frames = pair.seq
            self._latest = pair
            self._history[pair.seq] = pair
            self._history.pop(pair.seq - HISTORY, None)
            for p in self._pairs:
                p.after.pop(pair.seq - HISTORY, None)
            self._cond.notify_all()

    @property
    def latest(self) -> EncodedPair | None:
        """The newest published pair."""
        return self._latest

    # --- streaming --------------------------------------------------------------------------

    def _join(self, side: str) -> tuple[_Pair, int]:
        """The pair a new connection on `side` belongs to, and the first frame it sends."""
        now = time.monotonic()
        with self._cond:
            self._pairs = [p for p in self._pairs if p.sides or now - p.created < PAIR_WINDOW_S]
            for p in reversed(self._pairs):
                if side not in p.sides and now - p.created < PAIR_WINDOW_S and p.start in self._history:
                    p.sides.add(side)
                    return p, p.start
            assert self._latest is not None
            pair = _Pair(created=now, start=self._latest.seq, sides={side})
            self._pairs.append(pair)
            return pair, pair.start

    def _leave(self, pair: _Pair, side: str) -> None:
        with self._cond:
            pair.sides.discard(side)
            pair.created = 0.0 if not pair.sides else pair.created  # an emptied pair takes nobody new

    def _next(self, pair: _Pair, sent: int) -> EncodedPair | None:
        """The frame to send after `sent`: the pair's choice, else the newest (waiting for one)."""
        with self._cond:
            while not self.stop_event.is_set():
                chosen = pair.after.get(sent)
                if chosen is not None:
                    return self._history.get(chosen)  # None: this side fell HISTORY frames behind
                if self._latest is not None and self._latest.seq > sent:
                    pair.after[sent] = self._latest.seq
                    return self._latest
                self._cond.wait(timeout=0.5)
        return None

    def stream(self, side: str, sock: socket.socket, write: Callable[[bytes], None]) -> str:
        """Send `side`'s frames on one connection until the host leaves or the emulator stops."""
        pair, seq = self._join(side)
        self.on_event(f"{side} camera: client connected (frame {seq})")
        try:
            with self._cond:
                frame = self._history.get(seq)
            while frame is not None:
                data = frame.jpeg[side]
                head = f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(data)}\r\n\r\n"
                write(head.encode() + data + b"\r\n")
                self.sent[side] += 1
                frame = self._next(pair, frame.seq)
            return "stopped" if self.stop_event.is_set() else "fell behind"
        except (OSError, ValueError):
            return "closed"
        finally:
            self._leave(pair, side)
            self.on_event(f"{side} camera: client left")


def _without_noise(config: Any) -> Any:
    import dataclasses

    return dataclasses.replace(config, noise_std=0.0)


MAX_CONNECTIONS = 16
"""Connections the MJPEG server holds at once (a stereo pair needs 2; a few viewers more): beyond, a
newcomer is closed at once, so idle connections cannot pile up threads."""
REQUEST_TIMEOUT_S = 10.0
"""How long a connection may take to send its request line and headers before it is closed."""


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    emulator: CameraEmulator

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._connections: set[socket.socket] = set()
        self._conn_lock = threading.Lock()
        self._admitted = 0

    def verify_request(self, request: Any, client_address: Any) -> bool:
        """At most MAX_CONNECTIONS at once: a newcomer beyond is closed without a thread."""
        with self._conn_lock:
            if self._admitted >= MAX_CONNECTIONS:
                return False
            self._admitted += 1
            return True

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        with self._conn_lock:
            self._connections.add(request)
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._conn_lock:
                self._connections.discard(request)
                self._admitted -= 1

    def close_connections(self) -> None:
        """Shut every open stream down (the host's next read sees the end of the stream)."""
        with self._conn_lock:
            for sock in self._connections:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.0"
    server: _Server
    timeout = REQUEST_TIMEOUT_S  # for the request; a stream then has no timeout (see do_GET)

    def log_message(self, format: str, *args: Any) -> None:
        pass

    def do_GET(self) -> None:
        emulator = self.server.emulator
        side = self.path.split("?", 1)[0].strip("/").removesuffix(".mjpg")
        if side not in SIDES:
            body = b"twin camera emulator: /left.mjpg and /right.mjpg (MJPEG streams)\n"
            self.send_response(404 if self.path not in ("/", "") else 200)
            self.send_header("Content-Type", "text/plain")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        self.send_response(200)
        self.send_header("Content-Type", f"multipart/x-mixed-replace;boundary={BOUNDARY}")
        self.send_header("Cache-Control", "no-cache")
        self.send_header("Connection", "close")
        self.end_headers()
        sock = self.connection
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)  # no autotuning: bounded queue
        sock.settimeout(None)  # a host that stops reading stalls its own stream, as a camera would wait

        def write(data: bytes) -> None:
            self.wfile.write(data)
            self.wfile.flush()

        emulator.stream(side, sock, write)
