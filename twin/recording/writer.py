"""RunWriter: one run directory of multi-rate streams plus run.json.

Layout::

    <run_dir>/run.json               format, status, stream specs, caller metadata
    <run_dir>/streams/<name>.arrows  one Arrow IPC stream per stream, appended in record batches

Rows are buffered in memory and written as a record batch once they span ``flush_interval_s`` of
run time, or the oldest has waited ``flush_interval_s`` of wall time, and each write is flushed to
the OS. A killed process therefore loses only its buffered rows; the reader recovers every complete
batch. run.json is only ever replaced whole (temp file + os.replace), never half-written.

What a run directory promises:

- status: "running" while written (and forever, if the writer was killed: the reader then recovers
  every complete batch, and ``writer`` (PID, host, boot id, start time; twin.recording.liveness)
  lets a reader on the same host tell that the writer is gone); "complete" (every stream written to
  its end), "failed" or "interrupted", with ``error``: one line saying why, and what was verified
  after (the rig's stop, e.g. whether the hand acknowledged its idle). A "complete" run may carry
  ``warnings`` (a list of lines, e.g. a hand loop that missed its declared rate): the recording is
  whole, but something about it needs saying. ``run_id`` names the run wherever it is copied.
- time: every stream's ``t_s`` is seconds on the run's one clock (sim time; on hardware, wall time
  since the rig started), the clock every device of the backend reads; each stream's description
  says which instant of a sample it stamps (e.g. a reading when it was taken, a command when sent).
- integrity: a closed run's run.json holds each stream file's size and SHA-256 as written
  (``integrity``); the reader checks them and refuses a stream file changed since (RunFormatError).
  run.json itself is plain text and carries no digest.
- identity: everything is written through descriptors of the directory created, never by path, and
  its identity (device, inode) is checked at every flush and before run.json is written. A directory
  removed or replaced mid-run stops the run with RunDirectoryLostError, and nothing is ever written
  into a replacement.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import json
import math
import os
import time
import uuid
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
import pyarrow as pa
from numpy.typing import ArrayLike

from twin.interface.errors import RunDirectoryLostError
from twin.recording.liveness import writer_identity
from twin.recording.schema import FieldSpec, StreamSpec, arrow_schema, to_arrow

FORMAT = "barrett-twin-run"
FORMAT_VERSION = 1
RUN_FILE = "run.json"
STREAMS_DIR = "streams"
STREAM_SUFFIX = ".arrows"
STATUSES = frozenset({"complete", "failed", "interrupted"})
"""Final statuses accepted by ``RunWriter.close`` (a run being written is "running")."""
DIGEST = "sha256"
"""The digest of each stream file recorded in a closed run's run.json (``integrity``)."""
RESERVE_FILE = ".status-reserve"
"""Space held in the run directory while it is written, given up to write the final run.json when the
disk is full: a run stopped by a full disk still says so (status "failed"), not "running"."""
RESERVE_BYTES = 256 * 1024
_FULL = (errno.ENOSPC, errno.EDQUOT)
_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)


def _utc_now() -> str:
    """The current UTC time as ISO 8601."""
    return datetime.now(UTC).isoformat()


def _json_default(obj: object) -> Any:
    """Make numpy scalars/arrays and paths JSON-serialisable (for ``json.dumps(default=...)``)."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, tuple | set | frozenset):
        return list(obj)
    raise TypeError(f"metadata value of type {type(obj).__name__} is not JSON-serialisable")


def to_plain_json(obj: object) -> Any:
    """A detached copy of ``obj`` made of plain JSON types (numpy converted)."""
    return json.loads(json.dumps(obj, default=_json_default))


def write_json_atomic(path: Path, data: dict, dir_fd: int | None = None) -> None:
    """Write ``data`` to ``path`` via a synced temp file and os.replace, so it is never partial.

    With ``dir_fd`` the name is taken in that open directory (whatever its path now leads to)."""
    tmp = f".{path.name}.tmp"
    where = {"dir_fd": dir_fd} if dir_fd is not None else {}
    tmp_path, final = (tmp, path.name) if dir_fd is not None else (path.with_name(tmp), path)
    text = json.dumps(data, indent=2, default=_json_default)
    fd = os.open(tmp_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644, **where)
    try:
        with open(fd, "w", encoding="utf-8") as f:
            f.write(text + "\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp_path, final, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
    except BaseException:  # a full disk, an I/O error: no half-written temporary file left behind
        with contextlib.suppress(OSError):
            os.unlink(tmp_path, **where)
        raise


def file_digest(fd: int) -> dict[str, Any]:
    """Size and SHA-256 of an open file, read from its start (what run.json's ``integrity`` holds)."""
    digest = hashlib.sha256()
    size = 0
    offset = 0
    while chunk := os.pread(fd, 1 << 20, offset):
        digest.update(chunk)
        size += len(chunk)
        offset += len(chunk)
    return {"bytes": size, DIGEST: digest.hexdigest()}


def _check_run_dir(run_dir: Path) -> None:
    """Create ``run_dir``; FileExistsError if it is a file or a non-empty directory."""
    if run_dir.exists() or run_dir.is_symlink():
        if not run_dir.is_dir():
            raise FileExistsError(f"run directory {run_dir} exists and is not a directory")
        if any(run_dir.iterdir()):
            raise FileExistsError(f"run directory {run_dir} already exists and is not empty")
    run_dir.mkdir(parents=True, exist_ok=True)


def _with_path(exc: OSError, path: str) -> OSError:
    """The same error naming `path`, if it names no file (pyarrow's and a flush's do not)."""
    if exc.filename is not None or exc.errno is None:
        return exc
    return OSError(exc.errno, exc.strerror or str(exc), path)


class _StreamFile:
    """One open stream: its Arrow writer, its row buffer and its bookkeeping."""

    def __init__(self, spec: StreamSpec, name: str, dir_fd: int, shown: str = "") -> None:
        self.spec = spec
        self.name = name
        self.shown = shown or name
        """The file's path as an error names it."""
        self.schema = arrow_schema(spec)
        fd = os.open(name, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644, dir_fd=dir_fd)
        self.file: IO[bytes] = open(fd, "wb")  # noqa: SIM115 - closed in close()
        self.writer = pa.ipc.new_stream(self.file, self.schema)
        self.t: list[float] = []
        self.rows: dict[str, list[np.ndarray]] = {name: [] for name in spec.fields}
        self.first_wall = 0.0  # monotonic time the oldest buffered row arrived
        self.last_t = -math.inf
        self.written = 0

    def buffer(self, t_s: float, row: dict[str, np.ndarray], now: float) -> None:
        """Keep one validated sample until the next write."""
        if not self.t:
            self.first_wall = now
        self.t.append(t_s)
        for name, value in row.items():
            self.rows[name].append(value)
        self.last_t = t_s

    def due(self, interval_s: float, now: float) -> bool:
        """True when the buffer spans ``interval_s`` of run time or waited it in wall time."""
        if not self.t:
            return False
        return self.t[-1] - self.t[0] >= interval_s or now - self.first_wall >= interval_s

    def write(self) -> None:
        """Write the buffered rows as one record batch and push it to the OS."""
        if not self.t:
            return
        try:
            self._write()
        except OSError as exc:  # a full disk, an I/O error: the error names the file
            raise _with_path(exc, self.shown) from None

    def _write(self) -> None:
        columns = [pa.array(self.t, type=pa.float64())]
        for name, fspec in self.spec.fields.items():
            rows = self.rows[name]
            columns.append(to_arrow(rows if fspec.ragged else np.stack(rows), fspec))
        self.writer.write_batch(pa.record_batch(columns, schema=self.schema))
        self.file.flush()
        self.written += len(self.t)
        self.t.clear()
        for rows in self.rows.values():
            rows.clear()

    def close(self) -> dict[str, Any]:
        """Write what is buffered, end the Arrow stream, fsync and close the file; its digest."""
        try:
            self.write()
            self.writer.close()
            self.file.flush()
            os.fsync(self.file.fileno())
            return file_digest(self.file.fileno())
        except OSError as exc:
            raise _with_path(exc, self.shown) from None
        finally:
            with contextlib.suppress(OSError):  # (its buffer may not fit on a full disk either)
                self.file.close()

    def is_at(self, dir_fd: int) -> bool:
        """True while the stream's name in its directory still leads to the file being written."""
        try:
            named = os.stat(self.name, dir_fd=dir_fd)
        except OSError:
            return False
        if self.file.closed:
            return True
        return os.path.samestat(named, os.fstat(self.file.fileno()))


def _validate_row(spec: StreamSpec, values: Mapping[str, ArrayLike]) -> dict[str, np.ndarray]:
    """One sample's values cast to their declared dtypes; ValueError on names, shape or value."""
    if values.keys() != spec.fields.keys():
        missing = [name for name in spec.fields if name not in values]
        unknown = [name for name in values if name not in spec.fields]
        raise ValueError(
            f"stream {spec.name!r}: missing fields {missing}, unknown fields {unknown}; "
            f"declared {list(spec.fields)}"
        )
    return {name: _cast(spec.name, name, fspec, values[name]) for name, fspec in spec.fields.items()}


@functools.cache
def _dtype(name: str) -> np.dtype:
    """The numpy dtype of a declared dtype name (looked up once per name)."""
    return np.dtype(name)


def _cast(stream: str, name: str, spec: FieldSpec, value: ArrayLike) -> np.ndarray:
    """``value`` as spec.dtype; integer/bool targets must hold the value exactly (no truncation)."""
    arr = np.asarray(value)
    if spec.ragged:
        if arr.ndim != len(spec.shape) or arr.shape[1:] != spec.shape[1:]:
            raise ValueError(f"stream {stream!r} field {name!r}: shape {arr.shape}, declared {spec.shape}")
    elif arr.shape != spec.shape:
        raise ValueError(f"stream {stream!r} field {name!r}: shape {arr.shape}, declared {spec.shape}")
    if arr.dtype == _dtype(spec.dtype):  # already the declared dtype: nothing to convert or check
        return arr.copy()  # a copy all the same: the caller may change its array before the write
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"stream {stream!r} field {name!r}: non-numeric dtype {arr.dtype}")
    with np.errstate(invalid="ignore", over="ignore"):
        out = arr.astype(spec.dtype)
    if out.dtype.kind != "f" and not np.array_equal(out, arr):
        raise ValueError(f"stream {stream!r} field {name!r}: value {arr.tolist()} does not fit {spec.dtype}")
    return out


class RunWriter:
    """Writes one run directory; crash-safe: data reaches the OS at least every flush_interval_s."""

    def __init__(self, run_dir: Path | str, metadata: dict, *, flush_interval_s: float = 0.25) -> None:
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0, got {flush_interval_s}")
        self._run_dir = Path(run_dir)
        self._flush_interval_s = float(flush_interval_s)
        self._metadata: dict = to_plain_json(dict(metadata))
        self._streams: dict[str, _StreamFile] = {}
        self._closed = False
        self._info: dict = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "status": "running",
            "created_utc": _utc_now(),
            "run_id": uuid.uuid4().hex,
            "writer": writer_identity(),
            "streams": {},
            "warnings": [],
            "metadata": self._metadata,
        }
        _check_run_dir(self._run_dir)
        self._dir_fd = os.open(self._run_dir, _DIR_FLAGS)
        try:
            os.mkdir(STREAMS_DIR, dir_fd=self._dir_fd)
            self._streams_fd = os.open(STREAMS_DIR, _DIR_FLAGS, dir_fd=self._dir_fd)
        except BaseException:
            os.close(self._dir_fd)
            raise
        self._identity = (os.fstat(self._dir_fd), os.fstat(self._streams_fd))
        self._checked_s = time.monotonic()
        self._reserve()
        self._write_info()

    @property
    def run_dir(self) -> Path:
        """The run directory being written."""
        return self._run_dir

    @property
    def closed(self) -> bool:
        """True once close() has run (whatever it managed to write)."""
        return self._closed

    @property
    def warnings(self) -> list[str]:
        """The run's warnings so far (see ``warn``)."""
        return list(self._info["warnings"])

    def add_stream(self, spec: StreamSpec) -> None:
        """Declare a stream (before or during the run); ValueError on a duplicate name."""
        self.add_streams(spec)

    def add_streams(self, *specs: StreamSpec) -> None:
        """Declare several streams with one rewrite of run.json (each rewrite is synced to disk);
        TypeError or ValueError (a duplicate name), and none added, on a bad one."""
        self._check_open()
        names = set(self._streams)
        for spec in specs:
            if not isinstance(spec, StreamSpec):
                raise TypeError(f"add_stream expects a StreamSpec, got {type(spec).__name__}")
            if spec.name in names:
                raise ValueError(f"stream {spec.name!r} already added")
            names.add(spec.name)
        self.check_identity()
        for spec in specs:
            name = f"{spec.name}{STREAM_SUFFIX}"
            shown = str(self._run_dir / STREAMS_DIR / name)
            self._streams[spec.name] = _StreamFile(spec, name, self._streams_fd, shown)
            self._info["streams"][spec.name] = spec.to_json()
        self._write_info()

    def append(self, stream: str, t_s: float, values: Mapping[str, ArrayLike]) -> None:
        """Record one sample of ``stream`` at run time ``t_s`` (non-decreasing per stream).

        RunDirectoryLostError once the run directory has been removed or replaced (checked at most
        every flush interval of wall time)."""
        self._check_open()
        sf = self._streams.get(stream)
        if sf is None:
            raise ValueError(f"unknown stream {stream!r}; added: {list(self._streams)}")
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError(f"stream {stream!r}: t_s must be finite, got {t_s!r}")
        if t < sf.last_t:
            raise ValueError(f"stream {stream!r}: t_s {t} is before the previous {sf.last_t}")
        now = time.monotonic()
        sf.buffer(t, _validate_row(sf.spec, values), now)
        if now - self._checked_s >= self._flush_interval_s:
            self.check_identity()
            self._checked_s = now
        for other in self._streams.values():
            if other.due(self._flush_interval_s, now):
                other.write()

    def flush(self) -> None:
        """Write all buffered rows of all streams now."""
        self._check_open()
        self.check_identity()
        for sf in self._streams.values():
            sf.write()

    def update_metadata(self, **items: Any) -> None:
        """Merge ``items`` into the run metadata and rewrite run.json."""
        self._check_open()
        self._metadata.update(to_plain_json(items))
        self._write_info()

    def warn(self, message: str) -> None:
        """Add one line to the run's ``warnings`` (kept whatever the final status) and rewrite run.json."""
        self._check_open()
        self._info["warnings"].append(str(message))
        self._write_info()

    def check_identity(self) -> None:
        """RunDirectoryLostError unless the run directory, streams/ and every stream file are still
        the ones this writer created, at the path it was given."""
        if self._identity_intact():
            return
        status = "its status could not be written" if not self._closed else "run.json was not written"
        raise RunDirectoryLostError(
            f"the run directory {self._run_dir} was removed or replaced during the run; its recording is "
            f"lost ({status})"
        )

    def close(
        self, status: str = "complete", error: str | None = None, *, metadata: Mapping[str, Any] | None = None
    ) -> None:
        """Flush and fsync every stream, then record the final status in run.json (idempotent).

        Each stream file's size and SHA-256 go into run.json (``integrity``), and `metadata` merged
        into the run metadata, as update_metadata would, in the same final rewrite of run.json.
        RunDirectoryLostError, and nothing written, when the directory was removed or replaced meanwhile."""
        if status not in STATUSES:
            raise ValueError(f"status {status!r} not one of {sorted(STATUSES)}")
        if self._closed:
            return
        items = to_plain_json(dict(metadata or {}))  # a value that is not JSON fails here, nothing closed
        self._closed = True
        self._metadata.update(items)
        failure: BaseException | None = None
        digests: dict[str, dict] = {}
        for name, sf in self._streams.items():
            try:
                digests[name] = sf.close()
            except Exception as exc:  # record the failure, still close the other streams
                failure = failure or exc
        try:
            self.check_identity()
            if failure is not None and status == "complete":
                status, error = "failed", f"closing streams: {failure}"
            self._info.update(status=status, error=error, closed_utc=_utc_now())
            self._info["integrity"] = {"algorithm": DIGEST, "streams": digests}
            try:
                self._write_info(checked=True)
            except OSError as exc:
                if exc.errno not in _FULL:
                    raise
                self._release_reserve()  # the space held for this very write
                if status == "complete":
                    self._info.update(status="failed", error=f"writing run.json: {exc.strerror}")
                self._write_info(checked=True)
            self._release_reserve()
        finally:
            os.close(self._streams_fd)
            os.close(self._dir_fd)
        if failure is not None:
            raise failure

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc is None:
            self.close("complete")
        elif isinstance(exc, KeyboardInterrupt):
            self.close("interrupted")
        else:
            self.close("failed", error=str(exc) or type(exc).__name__)

    def _reserve(self) -> None:
        """Hold RESERVE_BYTES in the run directory for the final run.json (best effort)."""
        try:
            fd = os.open(RESERVE_FILE, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600, dir_fd=self._dir_fd)
        except OSError:
            return
        try:
            os.posix_fallocate(fd, 0, RESERVE_BYTES)
        except (OSError, AttributeError):
            with contextlib.suppress(OSError):
                os.write(fd, bytes(RESERVE_BYTES))
        finally:
            os.close(fd)

    def _release_reserve(self) -> None:
        with contextlib.suppress(OSError):
            os.unlink(RESERVE_FILE, dir_fd=self._dir_fd)

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"run {self._run_dir} is closed")

    def _identity_intact(self) -> bool:
        """The path still leads to the directory created, streams/ is the one made, files are ours."""
        run_identity, streams_identity = self._identity
        try:
            at_path = os.stat(self._run_dir)
            streams = os.stat(STREAMS_DIR, dir_fd=self._dir_fd)
        except OSError:
            return False
        if not (os.path.samestat(at_path, run_identity) and os.path.samestat(streams, streams_identity)):
            return False
        return all(sf.is_at(self._streams_fd) for sf in self._streams.values())

    def _write_info(self, checked: bool = False) -> None:
        """Rewrite run.json (atomically, in the directory created) with the current streams, sample
        counts and metadata; never into a directory that replaced it."""
        if not checked:
            self.check_identity()
        self._info["samples"] = {name: sf.written for name, sf in self._streams.items()}
        try:
            write_json_atomic(self._run_dir / RUN_FILE, self._info, dir_fd=self._dir_fd)
        except OSError as exc:
            raise _with_path(exc, str(self._run_dir / RUN_FILE)) from None
