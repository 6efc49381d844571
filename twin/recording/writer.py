"""RunWriter: one run directory of multi-rate streams plus run.json.

Layout::

    <run_dir>/run.json               format, status, stream specs, caller metadata
    <run_dir>/streams/<name>.arrows  one Arrow IPC stream per stream, appended in record batches

Rows are buffered in memory and written as a record batch once they span ``flush_interval_s`` of
run time, or the oldest has waited ``flush_interval_s`` of wall time, and each write is flushed to
the OS. A killed process therefore loses only its buffered rows; the reader recovers every complete
batch. run.json is only ever replaced whole (temp file + os.replace), never half-written.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
import pyarrow as pa
from numpy.typing import ArrayLike

from twin.recording.schema import FieldSpec, StreamSpec, arrow_schema, to_arrow

FORMAT = "barrett-twin-run"
FORMAT_VERSION = 1
RUN_FILE = "run.json"
STREAMS_DIR = "streams"
STREAM_SUFFIX = ".arrows"
STATUSES = frozenset({"complete", "failed", "interrupted"})
"""Final statuses accepted by ``RunWriter.close`` (a run being written is "running")."""


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


def write_json_atomic(path: Path, data: dict) -> None:
    """Write ``data`` to ``path`` via a synced temp file and os.replace, so it is never partial."""
    tmp = path.with_name(f".{path.name}.tmp")
    text = json.dumps(data, indent=2, default=_json_default)
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _check_run_dir(run_dir: Path) -> None:
    """Create ``run_dir``; FileExistsError if it is a file or a non-empty directory."""
    if run_dir.exists() or run_dir.is_symlink():
        if not run_dir.is_dir():
            raise FileExistsError(f"run directory {run_dir} exists and is not a directory")
        if any(run_dir.iterdir()):
            raise FileExistsError(f"run directory {run_dir} already exists and is not empty")
    run_dir.mkdir(parents=True, exist_ok=True)


class _StreamFile:
    """One open stream: its Arrow writer, its row buffer and its bookkeeping."""

    def __init__(self, spec: StreamSpec, path: Path) -> None:
        self.spec = spec
        self.schema = arrow_schema(spec)
        self.file: IO[bytes] = open(path, "wb")  # noqa: SIM115 - closed in close()
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

    def close(self) -> None:
        """Write what is buffered, end the Arrow stream, fsync and close the file."""
        try:
            self.write()
            self.writer.close()
            self.file.flush()
            os.fsync(self.file.fileno())
        finally:
            self.file.close()


def _validate_row(spec: StreamSpec, values: Mapping[str, ArrayLike]) -> dict[str, np.ndarray]:
    """One sample's values cast to their declared dtypes; ValueError on names, shape or value."""
    missing = [name for name in spec.fields if name not in values]
    unknown = [name for name in values if name not in spec.fields]
    if missing or unknown:
        raise ValueError(
            f"stream {spec.name!r}: missing fields {missing}, unknown fields {unknown}; "
            f"declared {list(spec.fields)}"
        )
    return {name: _cast(spec.name, name, fspec, values[name]) for name, fspec in spec.fields.items()}


def _cast(stream: str, name: str, spec: FieldSpec, value: ArrayLike) -> np.ndarray:
    """``value`` as spec.dtype; integer/bool targets must hold the value exactly (no truncation)."""
    arr = np.asarray(value)
    if spec.ragged:
        if arr.ndim != len(spec.shape) or arr.shape[1:] != spec.shape[1:]:
            raise ValueError(f"stream {stream!r} field {name!r}: shape {arr.shape}, declared {spec.shape}")
    elif arr.shape != spec.shape:
        raise ValueError(f"stream {stream!r} field {name!r}: shape {arr.shape}, declared {spec.shape}")
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
            "streams": {},
            "metadata": self._metadata,
        }
        _check_run_dir(self._run_dir)
        (self._run_dir / STREAMS_DIR).mkdir()
        self._write_info()

    @property
    def run_dir(self) -> Path:
        """The run directory being written."""
        return self._run_dir

    def add_stream(self, spec: StreamSpec) -> None:
        """Declare a stream (before or during the run); ValueError on a duplicate name."""
        self._check_open()
        if not isinstance(spec, StreamSpec):
            raise TypeError(f"add_stream expects a StreamSpec, got {type(spec).__name__}")
        if spec.name in self._streams:
            raise ValueError(f"stream {spec.name!r} already added")
        path = self._run_dir / STREAMS_DIR / f"{spec.name}{STREAM_SUFFIX}"
        self._streams[spec.name] = _StreamFile(spec, path)
        self._info["streams"][spec.name] = spec.to_json()
        self._write_info()

    def append(self, stream: str, t_s: float, values: Mapping[str, ArrayLike]) -> None:
        """Record one sample of ``stream`` at run time ``t_s`` (non-decreasing per stream)."""
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
        for other in self._streams.values():
            if other.due(self._flush_interval_s, now):
                other.write()

    def flush(self) -> None:
        """Write all buffered rows of all streams now."""
        self._check_open()
        for sf in self._streams.values():
            sf.write()

    def update_metadata(self, **items: Any) -> None:
        """Merge ``items`` into the run metadata and rewrite run.json."""
        self._check_open()
        self._metadata.update(to_plain_json(items))
        self._write_info()

    def close(self, status: str = "complete", error: str | None = None) -> None:
        """Flush and fsync every stream, then record the final status in run.json (idempotent)."""
        if status not in STATUSES:
            raise ValueError(f"status {status!r} not one of {sorted(STATUSES)}")
        if self._closed:
            return
        self._closed = True
        failure: BaseException | None = None
        for sf in self._streams.values():
            try:
                sf.close()
            except Exception as exc:  # record the failure, still close the other streams
                failure = failure or exc
        if failure is not None and status == "complete":
            status, error = "failed", f"closing streams: {failure}"
        self._info.update(status=status, error=error, closed_utc=_utc_now())
        self._write_info()
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

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"run {self._run_dir} is closed")

    def _write_info(self) -> None:
        """Rewrite run.json (atomically) with the current streams, sample counts and metadata."""
        self._info["samples"] = {name: sf.written for name, sf in self._streams.items()}
        write_json_atomic(self._run_dir / RUN_FILE, self._info)
