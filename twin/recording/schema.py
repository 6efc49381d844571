"""Stream and field declarations, and their mapping to Arrow schemas and columns.

A stream is a table sampled at its own rate: a float64 ``t_s`` column (run clock, seconds) first,
then one column per declared field. Scalar fields are primitive Arrow columns; shaped fields are
nested ``fixed_size_list`` columns (one level per dimension, row-major), so pandas, polars and
DuckDB see the structure without our code. A leading dimension of ``RAGGED`` (-1) varies from row to
row (a point cloud, a mesh, an encoded image): an Arrow ``list`` of the fixed inner shape, read back as
a list of arrays. Units, kinds and shapes travel as Arrow metadata.
"""

from __future__ import annotations

import itertools
import json
import math
import re
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa

TIME_FIELD = "t_s"
"""The implicit first column of every stream: sample time on the run clock, seconds."""

DTYPES: dict[str, pa.DataType] = {
    "float32": pa.float32(),
    "float64": pa.float64(),
    "int8": pa.int8(),
    "int16": pa.int16(),
    "int32": pa.int32(),
    "int64": pa.int64(),
    "uint8": pa.uint8(),
    "uint16": pa.uint16(),
    "uint32": pa.uint32(),
    "bool": pa.bool_(),
}
"""Accepted numpy dtype names and their Arrow types."""

KINDS = frozenset({"raw", "physical", "command", "truth", "status"})
"""What a field holds: hardware units, converted units, a command, sim ground truth, a state."""

_NAME = re.compile(r"[a-z0-9_]+")
RAGGED = -1
"""A leading field dimension whose length varies per sample, e.g. ``shape=(RAGGED, 3)`` for points."""


def _check_name(name: object, what: str) -> None:
    """Raise ValueError unless ``name`` is a non-empty [a-z0-9_]+ string."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ValueError(f"{what} name {name!r} must match [a-z0-9_]+")


@dataclass(frozen=True)
class FieldSpec:
    """One recorded quantity: unit, per-sample shape, dtype and kind."""

    unit: str
    shape: tuple[int, ...] = ()
    dtype: str = "float64"
    kind: str = "physical"
    description: str = ""

    def __post_init__(self) -> None:
        shape = tuple(self.shape)
        object.__setattr__(self, "shape", shape)  # accept lists (e.g. from JSON)
        if not isinstance(self.unit, str) or not self.unit:
            raise ValueError(f"field unit must be a non-empty string, got {self.unit!r}")
        dims = shape[1:] if shape and shape[0] == RAGGED else shape
        if not all(isinstance(d, int | np.integer) and d > 0 for d in dims):
            raise ValueError(f"field shape {shape} must be positive ints (the first may be {RAGGED}: ragged)")
        object.__setattr__(self, "shape", tuple(int(d) for d in shape))
        if self.dtype not in DTYPES:
            raise ValueError(f"field dtype {self.dtype!r} not one of {sorted(DTYPES)}")
        if self.kind not in KINDS:
            raise ValueError(f"field kind {self.kind!r} not one of {sorted(KINDS)}")

    @property
    def ragged(self) -> bool:
        """Whether the leading dimension varies from sample to sample."""
        return bool(self.shape) and self.shape[0] == RAGGED

    def to_json(self) -> dict:
        """A JSON-ready dict of this spec."""
        return {
            "unit": self.unit,
            "shape": list(self.shape),
            "dtype": self.dtype,
            "kind": self.kind,
            "description": self.description,
        }

    @classmethod
    def from_json(cls, d: dict) -> FieldSpec:
        """The spec that ``to_json`` produced."""
        return cls(
            unit=d["unit"],
            shape=tuple(d.get("shape", ())),
            dtype=d.get("dtype", "float64"),
            kind=d.get("kind", "physical"),
            description=d.get("description", ""),
        )


@dataclass(frozen=True)
class StreamSpec:
    """One stream: name, nominal rate and fields (``t_s`` is implicit and first)."""

    name: str
    rate_hz: float
    fields: dict[str, FieldSpec] = field(default_factory=dict)
    description: str = ""

    def __post_init__(self) -> None:
        _check_name(self.name, "stream")
        rate = self.rate_hz
        if isinstance(rate, bool) or not isinstance(rate, int | float) or not math.isfinite(rate):
            raise ValueError(f"stream {self.name!r}: rate_hz must be a finite number, got {rate!r}")
        if rate <= 0:
            raise ValueError(f"stream {self.name!r}: rate_hz must be > 0, got {rate}")
        object.__setattr__(self, "rate_hz", float(rate))
        object.__setattr__(self, "fields", dict(self.fields))  # detach from the caller's dict
        for fname, fspec in self.fields.items():
            _check_name(fname, f"stream {self.name!r}: field")
            if fname == TIME_FIELD:
                raise ValueError(f"stream {self.name!r}: field name {TIME_FIELD!r} is implicit")
            if not isinstance(fspec, FieldSpec):
                raise ValueError(f"stream {self.name!r}: field {fname!r} is not a FieldSpec")

    def to_json(self) -> dict:
        """A JSON-ready dict of this spec (as stored in run.json)."""
        return {
            "name": self.name,
            "rate_hz": self.rate_hz,
            "description": self.description,
            "fields": {name: f.to_json() for name, f in self.fields.items()},
        }

    @classmethod
    def from_json(cls, d: dict) -> StreamSpec:
        """The spec that ``to_json`` produced."""
        return cls(
            name=d["name"],
            rate_hz=d["rate_hz"],
            fields={name: FieldSpec.from_json(f) for name, f in d["fields"].items()},
            description=d.get("description", ""),
        )


def arrow_type(spec: FieldSpec) -> pa.DataType:
    """The Arrow type of one field: primitive, or one fixed_size_list level per dimension."""
    t = DTYPES[spec.dtype]
    for dim in reversed(spec.shape):
        t = pa.list_(t) if dim == RAGGED else pa.list_(t, dim)
    return t


def arrow_schema(spec: StreamSpec) -> pa.Schema:
    """The Arrow schema of a stream: ``t_s`` then each field, with units etc. as metadata."""
    time = pa.field(
        TIME_FIELD,
        pa.float64(),
        nullable=False,
        metadata={"unit": "s", "kind": "status", "shape": "[]", "description": "run clock"},
    )
    fields = [
        pa.field(
            name,
            arrow_type(f),
            nullable=False,
            metadata={
                "unit": f.unit,
                "kind": f.kind,
                "shape": json.dumps(list(f.shape)),
                "description": f.description,
            },
        )
        for name, f in spec.fields.items()
    ]
    meta = {"stream": spec.name, "rate_hz": repr(spec.rate_hz), "spec": json.dumps(spec.to_json())}
    return pa.schema([time, *fields], metadata=meta)


def to_arrow(values: np.ndarray | list[np.ndarray], spec: FieldSpec) -> pa.Array:
    """An (n, *shape) numpy array (ragged: a list of n (k_i, *inner) arrays) as an Arrow column."""
    if spec.ragged:
        rows = [np.ascontiguousarray(v).reshape(-1) for v in values]
        inner = math.prod(spec.shape[1:])
        lengths = np.array([len(r) // inner for r in rows], dtype=np.int32)
        flat = np.concatenate(rows) if rows else np.zeros(0)
        arr: pa.Array = pa.array(flat.astype(spec.dtype, copy=False), type=DTYPES[spec.dtype])
        for dim in reversed(spec.shape[1:]):
            arr = pa.FixedSizeListArray.from_arrays(arr, dim)
        offsets = pa.array(np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32))
        return pa.ListArray.from_arrays(offsets, arr)
    arr = pa.array(np.ascontiguousarray(values).reshape(-1), type=DTYPES[spec.dtype])
    for dim in reversed(spec.shape):
        arr = pa.FixedSizeListArray.from_arrays(arr, dim)
    return arr


def to_numpy(column: pa.Array | pa.ChunkedArray, spec: FieldSpec) -> np.ndarray | list[np.ndarray]:
    """An Arrow column of ``arrow_type(spec)`` as a writable (n, *shape) array of spec.dtype
    (ragged: a list of n (k_i, *inner) arrays)."""
    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    n = len(column)
    if spec.ragged:
        offsets = column.offsets.to_numpy() - column.offsets[0].as_py()
        inner = spec.shape[1:]
        values = column.flatten()
        for _ in inner:
            values = values.flatten()
        flat = np.array(values.to_numpy(zero_copy_only=False), dtype=spec.dtype)
        size = math.prod(inner)
        return [flat[a * size : b * size].reshape((-1, *inner)) for a, b in itertools.pairwise(offsets)]
    for _ in spec.shape:
        column = column.flatten()
    flat = column.to_numpy(zero_copy_only=False)
    return np.array(flat, dtype=spec.dtype).reshape((n, *spec.shape))
