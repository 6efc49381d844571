"""Plain Parquet: one table per stream, every run's rows in it (`run` and `episode_index` columns).

Vectors are fixed-size lists, the JPEG frames variable-length byte lists; `t_s` is the run clock.
`runs.json` keeps each run's path, status and metadata. pandas, polars and `datasets` read them as is.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from twin.recording import open_run


def _column(values: np.ndarray | list) -> pa.Array:
    """A field's values as an Arrow column: scalars plain, vectors fixed-size lists, ragged lists."""
    if isinstance(values, list) or values.dtype == object:  # ragged: one array per sample
        return pa.array([np.asarray(v).reshape(-1) for v in values])
    if values.ndim == 1:
        return pa.array(values)
    width = int(np.prod(values.shape[1:]))  # (not -1: a stream with no samples has nothing to infer from)
    flat = np.ascontiguousarray(values).reshape(len(values), width)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1)), flat.shape[1])


def write_tables(runs: list[Path], out: Path) -> Path:
    """out/<stream>.parquet for every stream any run has, and out/runs.json."""
    tables: dict[str, list[pa.Table]] = {}
    index = []
    for episode, path in enumerate(runs):
        run = open_run(path)
        index.append({"episode_index": episode, "run": str(run.path), "status": run.status,
                      "metadata": run.metadata})  # fmt: skip
        for name in run.streams:
            data = run.stream(name)
            n = len(data)
            columns = {
                "run": pa.array([run.path.name] * n, pa.string()),
                "episode_index": pa.array(np.full(n, episode, dtype=np.int64)),
                "t_s": pa.array(data.t_s),
                **{field: _column(values) for field, values in data.fields.items()},
            }
            tables.setdefault(name, []).append(pa.table(columns))
    out.mkdir(parents=True, exist_ok=True)  # (twin.export writes into a fresh temporary directory)
    for name, parts in tables.items():
        pq.write_table(pa.concat_tables(parts, promote_options="default"), out / f"{name}.parquet")
    (out / "runs.json").write_text(json.dumps(index, indent=1, default=str))
    return out
