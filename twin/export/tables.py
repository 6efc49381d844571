"""Plain Parquet: one table per stream, every run's rows in it, each column's unit and description with it.

Columns: `run_id` (run.json's id: unique, kept by copies), `run` (the run's directory relative to the
deepest folder holding every exported run, twin.export.identity), `episode_index` (the run's place in
the export), `hand_sample` (the join key, below), `t_s` (the run clock) and the stream's fields as
recorded: scalars plain, vectors fixed-size lists (row-major; the field's `shape` in its metadata),
ragged fields (JPEG bytes, point clouds) variable-length lists.

Meaning travels in the files: every column's Arrow field metadata holds `unit`, `description` (and for
the stream's fields `kind`, `shape`) exactly as the recorder declared them in the run (run.json's
stream specs, twin.recording.schema.arrow_schema: one source, not restated here); the file's key-value
metadata, which any Parquet reader lists (DuckDB's `parquet_kv_metadata`), repeats them as
`unit:<column>` and `description:<column>` beside `stream` and `stream_description`. `runs.json` lists
each run: episode_index, run_id, run, status, its stream specs (units, shapes, kinds, descriptions,
rates) and its metadata. Runs that recorded one field in different units are refused, not mixed.

One key across a run's tables: the streams are stamped when each sample was taken or sent, so their
`t_s` differ (a command goes out one latency after the reading it answers, ~4 ms in the sim) and a join
on `t_s` matches nothing. `hand_sample` is the row number (from 0, per run) of the hand reading at or
before each row on the run clock: a hand row's own, the reading a command answers (the rig sends a
command in answer to each reading, before the next), the latest reading when a scan or stereo pair was
taken; null before the first reading. Join on `(run_id, hand_sample)`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from twin.export.frames import held_index
from twin.export.identity import run_id, run_names
from twin.interface.errors import ConfigError
from twin.recording import Run, StreamSpec, open_run
from twin.recording.schema import TIME_FIELD, arrow_schema

KEY_COLUMNS = {
    "run_id": "the run's id (run.json run_id): unique, kept by copies of the run directory",
    "run": "the run's directory relative to the deepest folder holding every exported run",
    "episode_index": "the run's place in this export (runs.json)",
    "hand_sample": (
        "row number (per run, from 0) of the hand reading at or before this row on the run clock: a hand "
        "row's own, the reading a command answers, the latest reading when a scan or frame was taken; "
        "join a run's tables on (run_id, hand_sample)"
    ),
}
"""The columns the export adds before each stream's own, with their descriptions (unit "1")."""


def _column(values: np.ndarray | list) -> pa.Array:
    """A field's values as an Arrow column: scalars plain, vectors fixed-size lists, ragged lists."""
    if isinstance(values, list) or values.dtype == object:  # ragged: one array per sample
        return pa.array([np.asarray(v).reshape(-1) for v in values])
    if values.ndim == 1:
        return pa.array(values)
    width = int(np.prod(values.shape[1:]))  # (not -1: a stream with no samples has nothing to infer from)
    flat = np.ascontiguousarray(values).reshape(len(values), width)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1)), flat.shape[1])


def _hand_samples(run: Run, name: str, t_s: np.ndarray) -> pa.Array:
    """Each row's hand reading (its row number in the run's hand stream), null before the first."""
    if name == "hand":
        return pa.array(np.arange(len(t_s), dtype=np.int64))
    if "hand" not in run.streams or not len(t_s):
        return pa.nulls(len(t_s), pa.int64())
    at = held_index(run.stream("hand").t_s, t_s)
    return pa.array(at, pa.int64(), mask=at < 0)


def _column_meta(name: str, specs: list[tuple[str, StreamSpec]]) -> dict[str, dict[str, str]]:
    """Each recorded column's Arrow metadata as the runs' recorder declared it (unit, kind, shape,
    description); ConfigError where two runs declared a field's unit or shape differently."""
    meta: dict[str, dict[str, str]] = {}
    first: dict[str, str] = {}
    for run_name, spec in specs:
        for field in arrow_schema(spec):
            declared = {k.decode(): v.decode() for k, v in (field.metadata or {}).items()}
            known = meta.setdefault(field.name, declared)
            first.setdefault(field.name, run_name)
            for key in ("unit", "shape"):
                if known.get(key) != declared.get(key):
                    raise ConfigError(
                        f"{name}.{field.name}: {key} {known.get(key)} in {first[field.name]} but "
                        f"{declared.get(key)} in {run_name}; export such runs separately"
                    )
            if not known.get("description") and declared.get("description"):
                known["description"] = declared["description"]
    return meta


def _with_meaning(table: pa.Table, name: str, specs: list[tuple[str, StreamSpec]]) -> pa.Table:
    """The table with every column's unit and description in its field and in the file's metadata."""
    recorded = _column_meta(name, specs)
    fields, file_meta = [], {"stream": name}
    descriptions = [s.description for _, s in specs if s.description]
    if descriptions:
        file_meta["stream_description"] = descriptions[0]
    rates = {s.rate_hz for _, s in specs}
    if len(rates) == 1:
        file_meta["rate_hz"] = repr(rates.pop())
    for field in table.schema:
        if field.name in KEY_COLUMNS:
            meta = {"unit": "1", "description": KEY_COLUMNS[field.name]}
        else:
            meta = recorded[field.name]
        fields.append(field.with_metadata(meta))
        file_meta[f"unit:{field.name}"] = meta["unit"]
        file_meta[f"description:{field.name}"] = meta.get("description", "")
    return pa.Table.from_arrays(table.columns, schema=pa.schema(fields, metadata=file_meta))


def write_tables(runs: list[Path], out: Path) -> Path:
    """out/<stream>.parquet for every stream any run has, and out/runs.json."""
    tables: dict[str, list[pa.Table]] = {}
    specs: dict[str, list[tuple[str, StreamSpec]]] = {}
    index = []
    for episode, (path, name) in enumerate(zip(runs, run_names(runs), strict=True)):
        run = open_run(path)
        identity = run_id(run)
        index.append(
            {
                "episode_index": episode,
                "run_id": identity,
                "run": name,
                "status": run.status,
                "streams": {s: spec.to_json() for s, spec in run.streams.items()},
                "metadata": run.metadata,
            }
        )
        for stream, spec in run.streams.items():
            data = run.stream(stream)
            n = len(data)
            columns = {
                "run_id": pa.array([identity] * n, pa.string()),
                "run": pa.array([name] * n, pa.string()),
                "episode_index": pa.array(np.full(n, episode, dtype=np.int64)),
                "hand_sample": _hand_samples(run, stream, data.t_s),
                TIME_FIELD: pa.array(data.t_s),
                **{field: _column(values) for field, values in data.fields.items()},
            }
            tables.setdefault(stream, []).append(pa.table(columns))
            specs.setdefault(stream, []).append((name, spec))
    out.mkdir(parents=True, exist_ok=True)  # (twin.export writes into a fresh temporary directory)
    for stream, parts in tables.items():
        table = _with_meaning(pa.concat_tables(parts, promote_options="default"), stream, specs[stream])
        pq.write_table(table, out / f"{stream}.parquet")
    (out / "runs.json").write_text(json.dumps(index, indent=1, default=str))
    return out
