"""Read a run directory back, with no writer state, including runs whose writer was killed.

A stream file cut mid-batch (SIGKILL, power loss) yields every complete record batch; the stream
is then listed in ``Run.truncated``. A run whose writer never closed keeps status "running".

A closed run's stream files are checked against the size and SHA-256 its writer recorded at close
(run.json ``integrity``): a file changed since (one byte flipped, cut, replaced) raises RunFormatError
when read, and ``Run.corrupt_streams()`` lists such files without raising. A run without digests
(killed writer, older runs) is read with the crash recovery above.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from twin.interface.errors import TwinError
from twin.recording.schema import RAGGED, TIME_FIELD, StreamSpec, arrow_schema, to_numpy
from twin.recording.writer import DIGEST, FORMAT, FORMAT_VERSION, RUN_FILE, STREAM_SUFFIX, STREAMS_DIR


class RunFormatError(TwinError, ValueError):
    """The directory is not a readable barrett-twin run (missing/corrupt run.json or stream)."""


@dataclass
class StreamData:
    """One stream read back: timestamps and per-field arrays of shape (n, *shape)."""

    spec: StreamSpec
    t_s: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        """The ``t_s`` column or a field; KeyError lists the available names."""
        if name == TIME_FIELD:
            return self.t_s
        if name not in self.fields:
            raise KeyError(
                f"stream {self.spec.name!r} has no field {name!r}; available: {[TIME_FIELD, *self.fields]}"
            )
        return self.fields[name]

    def __len__(self) -> int:
        return len(self.t_s)

    def __repr__(self) -> str:
        """The stream at a glance, not its data: name, samples, time span and rate, then one line per
        column with its shape (n, ...; `k` a per-sample length), dtype, unit and kind."""
        n, spec = len(self.t_s), self.spec
        span = f"{n} samples, t = {self.t_s[0]:.3f} to {self.t_s[-1]:.3f} s" if n else "no samples"
        rate = self.measured_rate_hz()
        measured = f", {rate:.3g} Hz" if math.isfinite(rate) else ""
        rows = [(TIME_FIELD, f"({n},)", "float64", "s", "time")]
        for name in self.fields:
            f = spec.fields[name]
            dims = ", ".join("k" if d == RAGGED else str(d) for d in f.shape)
            rows.append((name, f"({n}, {dims})" if dims else f"({n},)", f.dtype, f.unit, f.kind))
        widths = [max(len(row[i]) for row in rows) for i in range(4)]
        lines = [f"StreamData {spec.name!r}: {span}{measured} (declared {spec.rate_hz:g} Hz)"]
        lines += [
            "  " + "  ".join(v.ljust(w) for v, w in zip(row, [*widths, 0], strict=True)).rstrip()
            for row in rows
        ]
        return "\n".join(lines)

    def measured_rate_hz(self) -> float:
        """Mean sample rate (n-1)/(t[-1]-t[0]); nan with fewer than 2 samples or zero duration."""
        n = len(self.t_s)
        duration = float(self.t_s[-1] - self.t_s[0]) if n else 0.0
        return (n - 1) / duration if n >= 2 and duration > 0 else math.nan


def _read_batches(path: Path, data: bytes, schema: pa.Schema) -> tuple[list[pa.RecordBatch], bool]:
    """Every complete record batch in an Arrow stream file's bytes, and whether it ended mid-message."""
    if not data:
        return [], False  # the writer never wrote a batch (the schema goes out with the first)
    try:
        reader = pa.ipc.open_stream(pa.BufferReader(data))
    except (pa.ArrowInvalid, OSError):
        return [], True  # partial schema message
    if not reader.schema.equals(schema):
        raise RunFormatError(f"{path}: schema does not match the stream spec in run.json")
    batches = []
    while True:
        try:
            batches.append(reader.read_next_batch())
        except StopIteration:
            return batches, False
        except (pa.ArrowInvalid, OSError, EOFError):
            return batches, True


class Run:
    """A run directory read back with no writer state."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self.info: dict = _load_info(self.path)
        self.metadata: dict = self.info.get("metadata", {})
        self.status: str = self.info["status"]
        self.streams: dict[str, StreamSpec] = _load_specs(self.info, self.path)
        self.digests: dict[str, dict] = _load_digests(self.info, self.path)
        """Per stream, the size and SHA-256 recorded at close (empty for a run that never closed)."""
        self.warnings: list[str] = _load_warnings(self.info, self.path)
        """What the run said needs saying (e.g. a hand loop that missed its rate); status may be complete."""
        self._data: dict[str, StreamData] = {}
        self._truncated: set[str] = set()

    @property
    def truncated(self) -> set[str]:
        """Streams whose file ended in a partial batch (reads every stream once)."""
        for name in self.streams:
            self.stream(name)
        return set(self._truncated)

    def stream(self, name: str) -> StreamData:
        """The stream's data (read once, then cached); KeyError lists the available names."""
        if name not in self.streams:
            raise KeyError(f"run {self.path} has no stream {name!r}; available: {list(self.streams)}")
        if name not in self._data:
            self._data[name] = self._read_stream(self.streams[name])
        return self._data[name]

    def corrupt_streams(self) -> dict[str, str]:
        """Streams whose file differs from what the writer recorded at close (or is missing): one line
        each. Empty for an intact run, and for a run without digests (only crash recovery applies)."""
        problems = {}
        for name in self.streams:
            try:
                self.stream(name)
            except RunFormatError as exc:
                problems[name] = str(exc)
        return problems

    def sample_mismatches(self) -> dict[str, tuple[int, int]]:
        """Streams whose readable samples differ from run.json's count: {stream: (recorded, readable)}.

        A closed run should have none. A run whose writer was killed has counts from its last
        run.json write (usually fewer than readable); a cut file has fewer readable than recorded."""
        recorded = self.info.get("samples")
        recorded = recorded if isinstance(recorded, dict) else {}
        out = {}
        for name in self.streams:
            count = recorded.get(name, 0)
            count = count if isinstance(count, int) and not isinstance(count, bool) else -1
            readable = len(self.stream(name))
            if count != readable:
                out[name] = (count, readable)
        return out

    def summary(self) -> list[dict]:
        """Per stream: name, samples, nominal and measured rate, duration and field descriptions."""
        rows = []
        for name, spec in self.streams.items():
            data = self.stream(name)
            t = data.t_s
            rows.append(
                {
                    "name": name,
                    "samples": len(data),
                    "rate_hz": spec.rate_hz,
                    "measured_rate_hz": data.measured_rate_hz(),
                    "duration_s": float(t[-1] - t[0]) if len(t) else 0.0,
                    "truncated": name in self._truncated,
                    "fields": {
                        f: {"unit": s.unit, "kind": s.kind, "shape": s.shape, "dtype": s.dtype}
                        for f, s in spec.fields.items()
                    },
                }
            )
        return rows

    def _read_stream(self, spec: StreamSpec) -> StreamData:
        """Read one stream file, recovering the complete batches of a cut file."""
        path = self.path / STREAMS_DIR / f"{spec.name}{STREAM_SUFFIX}"
        if not path.is_file():
            raise RunFormatError(f"run {self.path}: stream file {path.name} is missing")
        schema = arrow_schema(spec)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise RunFormatError(f"run {self.path}: stream file {path.name} is unreadable: {exc}") from None
        self._check_digest(spec.name, path, data)
        batches, cut = _read_batches(path, data, schema)
        if cut:
            self._truncated.add(spec.name)
        table = pa.Table.from_batches(batches, schema=schema)
        t_s = np.array(table.column(TIME_FIELD).to_numpy(), dtype=np.float64)
        fields = {name: to_numpy(table.column(name), f) for name, f in spec.fields.items()}
        return StreamData(spec=spec, t_s=t_s, fields=fields)

    def _check_digest(self, name: str, path: Path, data: bytes) -> None:
        """RunFormatError if the file is not what the writer closed (size or SHA-256)."""
        recorded = self.digests.get(name)
        if recorded is None:
            return
        if len(data) != recorded["bytes"] or hashlib.sha256(data).hexdigest() != recorded[DIGEST]:
            raise RunFormatError(
                f"run {self.path}: stream file {path.name} is corrupt: it changed after the run closed "
                f"({len(data)} bytes, {recorded['bytes']} recorded; the SHA-256 differs from run.json's)"
            )

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r}, status={self.status!r}, streams={list(self.streams)})"


def _load_info(path: Path) -> dict:
    """run.json of ``path``, checked to be a barrett-twin run of a version this code reads."""
    if not path.is_dir():
        raise RunFormatError(f"{path} is not a directory")
    info_path = path / RUN_FILE
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RunFormatError(f"{path} has no {RUN_FILE}; not a barrett-twin run") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RunFormatError(f"{info_path} is unreadable: {exc}") from None
    except RecursionError:
        raise RunFormatError(f"{info_path} is unreadable: nested too deeply") from None
    if not isinstance(info, dict) or info.get("format") != FORMAT:
        raise RunFormatError(f"{info_path} is not a {FORMAT} file")
    if info.get("format_version") != FORMAT_VERSION:
        raise RunFormatError(
            f"{info_path}: format_version {info.get('format_version')!r} unsupported "
            f"(this code reads {FORMAT_VERSION})"
        )
    if not isinstance(info.get("status"), str):
        raise RunFormatError(f"{info_path} has no status")
    return info


def _load_specs(info: dict, path: Path) -> dict[str, StreamSpec]:
    """The stream specs declared in run.json; RunFormatError if any is malformed, or filed under a key
    that is not its own (checked) name: every reader (export, info, compare) may then use a key as a
    file name, and none can name a path outside the run."""
    try:
        specs = {key: StreamSpec.from_json(d) for key, d in info["streams"].items()}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise RunFormatError(f"{path / RUN_FILE}: bad stream spec: {exc!r}") from None
    for key, spec in specs.items():
        if key != spec.name:
            raise RunFormatError(
                f"{path / RUN_FILE}: stream key {key!r} is not its spec's name {spec.name!r}"
            )
    return specs


def _load_digests(info: dict, path: Path) -> dict[str, dict]:
    """The per-stream digests of a closed run (run.json ``integrity``), checked for shape."""
    integrity = info.get("integrity")
    if integrity is None:
        return {}
    streams = integrity.get("streams") if isinstance(integrity, dict) else None
    ok = (
        isinstance(streams, dict)
        and integrity.get("algorithm") == DIGEST
        and all(
            isinstance(d, dict)
            and isinstance(d.get("bytes"), int)
            and isinstance(d.get(DIGEST), str)
            and name in info["streams"]
            for name, d in streams.items()
        )
    )
    if not ok:
        raise RunFormatError(f"{path / RUN_FILE}: malformed 'integrity' (per-stream bytes and {DIGEST})")
    return streams


def _load_warnings(info: dict, path: Path) -> list[str]:
    """The run's warning lines (absent in runs written before warnings existed)."""
    warnings = info.get("warnings", [])
    if not isinstance(warnings, list) or not all(isinstance(w, str) for w in warnings):
        raise RunFormatError(f"{path / RUN_FILE}: 'warnings' is not a list of lines")
    return warnings


def open_run(path: Path | str) -> Run:
    """Open a run directory; RunFormatError if it is not a readable barrett-twin run."""
    return Run(path)
