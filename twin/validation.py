"""One validator for every number and path a user hands the twin: the CLI's flags (argparse `type=`
factories) and rig.toml's keys (`check_number`).

A number must be finite (no nan, no +-inf, no 1e309) and inside its range; a path must be non-empty,
free of NUL bytes, and what the command expects there (an existing run, a new directory, a file whose
directory exists). Checked where the value enters, before anything heavy is imported, simulated or
written, so a bad value costs one line and exit status 2."""

from __future__ import annotations

import argparse
import math
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from twin.interface.errors import ConfigError

DAY_S = 86_400.0
"""The longest run or trajectory a flag accepts (s)."""
MIN_DURATION_S = 1e-3
"""The shortest run a flag accepts (s): 5e-324 is a number, not a run length."""
SEED_LIMIT = 2**32
"""Seeds are numpy seeds: 0 <= seed < 2**32."""


@dataclass(frozen=True)
class NumberRange:
    """What a number may be: int or float, and its bounds (None: unbounded on that side)."""

    kind: type = float
    min: float | None = None
    max: float | None = None
    min_inclusive: bool = True
    max_inclusive: bool = True

    def describe(self) -> str:
        """The range in words, e.g. 'a finite number > 0 and <= 86400'."""
        noun = "an integer" if self.kind is int else "a finite number"
        bounds = []
        if self.min is not None:
            bounds.append(f"{'>=' if self.min_inclusive else '>'} {_number(self.min, self.kind)}")
        if self.max is not None:
            bounds.append(f"{'<=' if self.max_inclusive else '<'} {_number(self.max, self.kind)}")
        return f"{noun} {' and '.join(bounds)}".rstrip()

    def contains(self, value: float) -> bool:
        """Whether a finite `value` lies inside the bounds."""
        if self.min is not None and not (value >= self.min if self.min_inclusive else value > self.min):
            return False
        return self.max is None or (value <= self.max if self.max_inclusive else value < self.max)

    def check(self, value: object) -> int | float:
        """`value` as this range's kind; ValueError ('must be ...') unless it is one and fits."""
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        ok = ok and not (self.kind is int and not isinstance(value, int))
        ok = ok and (isinstance(value, int) or math.isfinite(value)) and self.contains(value)  # type: ignore
        if not ok:
            raise ValueError(f"must be {self.describe()}")
        return self.kind(value)


def _number(value: float, kind: type) -> str:
    """A bound as people write it: 4294967295 for an integer, 86400, 1e+09 or 0.5 for a float."""
    return str(int(value)) if kind is int else f"{value:g}"


def _shown(text: str) -> str:
    """The user's text, quoted and cut to a readable length."""
    return repr(text) if len(text) <= 40 else repr(text[:40]) + "..."


def check_number(value: object, name: str, **bounds: object) -> int | float:
    """`value` checked against NumberRange(**bounds); ConfigError '<name> must be ..., got ...'."""
    try:
        return NumberRange(**bounds).check(value)  # type: ignore[arg-type]
    except ValueError as exc:
        raise ConfigError(f"{name} {exc}, got {value!r}") from None


_INTEGER = re.compile(r"[+-]?[0-9]+")
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


def parse_decimal(text: str, kind: type = float) -> int | float:
    """A plain ASCII decimal as `kind`: digits, one point, an exponent (floats), a sign; ValueError for
    anything else Python would take (`0_5`, Arabic-Indic or full-width digits, 'nan', 'inf', spaces)."""
    pattern = _INTEGER if kind is int else _DECIMAL
    if not isinstance(text, str) or not pattern.fullmatch(text):
        raise ValueError(f"not a plain decimal number: {text!r:.40}")
    return int(text, 10) if kind is int else float(text)


class NumberArg:
    """An argparse `type=`: parses the text as the range's kind and checks it (argparse names the flag)."""

    def __init__(self, rng: NumberRange) -> None:
        self.range = rng
        self.__name__ = "integer" if rng.kind is int else "number"  # argparse's 'invalid <name> value'

    def __call__(self, text: str) -> int | float:
        try:
            value = parse_decimal(text, self.range.kind)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"must be {self.range.describe()}, got {_shown(text)}") from None
        try:
            return self.range.check(value)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(f"{exc}, got {_shown(text)}") from None


def finite(
    min: float | None = None,
    max: float | None = None,
    *,
    min_inclusive: bool = True,
    max_inclusive: bool = True,
) -> NumberArg:
    """argparse type: a finite float within the bounds."""
    return NumberArg(NumberRange(float, min, max, min_inclusive, max_inclusive))


def integer(min: int | None = None, max: int | None = None) -> NumberArg:
    """argparse type: a decimal integer within the bounds (inclusive)."""
    return NumberArg(NumberRange(int, min, max))


def seed() -> NumberArg:
    """argparse type: a numpy seed, 0 <= seed < 2**32."""
    return integer(0, SEED_LIMIT - 1)


def duration(min_s: float = 0.0) -> NumberArg:
    """argparse type: a run length > min_s (and at least MIN_DURATION_S) and at most a day (s)."""
    if min_s < MIN_DURATION_S:
        return finite(MIN_DURATION_S, DAY_S)
    return finite(min_s, DAY_S, min_inclusive=False)


# --- paths ---------------------------------------------------------------------------------------


def _mode(path: Path) -> int | None:
    """st_mode of path, or None when there is nothing there (or the name cannot exist)."""
    try:
        return os.stat(path).st_mode
    except (OSError, ValueError):
        return None


def _plain(text: str) -> Path:
    if not text:
        raise argparse.ArgumentTypeError("empty path")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"{text!r}: a path cannot hold a NUL byte")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:  # undecodable bytes (surrogate escapes): Rerun and JSON cannot name it
        shown = os.fsencode(text).decode("utf-8", "backslashreplace")
        raise argparse.ArgumentTypeError(f"{shown}: not a UTF-8 name; rename it") from None
    return Path(text)


class PathArg:
    """An argparse `type=` for a path; `role` says what must be there (see the factories below)."""

    def __init__(self, role: str, contains: str | None = None, what: str = "") -> None:
        self.role, self.contains, self.what = role, contains, what
        self.__name__ = "path"

    def __call__(self, text: str) -> Path:
        path = _plain(text)
        check = getattr(self, f"_{self.role}")
        check(path)
        return path

    def _dir(self, path: Path) -> None:
        mode = _mode(path)
        expected = f"not {self.what}" if self.what else "not a directory"
        if mode is None:
            raise argparse.ArgumentTypeError(f"{path}: {expected} (no such directory)")
        if not stat.S_ISDIR(mode):
            raise argparse.ArgumentTypeError(f"{path}: {expected} (not a directory)")
        if self.contains and not stat.S_ISREG(_mode(path / self.contains) or 0):
            raise argparse.ArgumentTypeError(f"{path}: not {self.what} (no {self.contains})")

    def _file(self, path: Path) -> None:
        mode = _mode(path)
        if mode is None:
            raise argparse.ArgumentTypeError(f"{path}: no such file")
        if not stat.S_ISREG(mode):
            raise argparse.ArgumentTypeError(f"{path}: not a file")

    def _out_dir(self, path: Path) -> None:
        mode = _mode(path)
        if mode is not None and not stat.S_ISDIR(mode):
            raise argparse.ArgumentTypeError(f"{path}: exists and is not a directory")
        _parent_is_dir(path)

    def _new_dir(self, path: Path) -> None:
        self._out_dir(path)
        if _mode(path) is not None and any(path.iterdir()):
            raise argparse.ArgumentTypeError(f"{path}: directory is not empty; choose a new one")

    def _out_file(self, path: Path) -> None:
        mode = _mode(path)
        if mode is not None and stat.S_ISDIR(mode):
            raise argparse.ArgumentTypeError(f"{path}: is a directory")
        parent = path.parent
        if not stat.S_ISDIR(_mode(parent) or 0):
            raise argparse.ArgumentTypeError(f"{path}: no such directory {parent}")

    def _out_file_tree(self, path: Path) -> None:
        mode = _mode(path)
        if mode is not None and stat.S_ISDIR(mode):
            raise argparse.ArgumentTypeError(f"{path}: is a directory")
        _parent_is_dir(path)


def _parent_is_dir(path: Path) -> None:
    """The nearest existing ancestor of path must be a directory (else it can never be created)."""
    parent = path.parent
    while _mode(parent) is None and parent != parent.parent:
        parent = parent.parent
    if not stat.S_ISDIR(_mode(parent) or 0):
        raise argparse.ArgumentTypeError(f"{path}: {parent} is not a directory")


def existing_dir(contains: str | None = None, what: str = "") -> PathArg:
    """argparse type: an existing directory (holding the file `contains`, e.g. a run's run.json)."""
    return PathArg("dir", contains, what)


def existing_file() -> PathArg:
    """argparse type: an existing regular file."""
    return PathArg("file")


def out_dir() -> PathArg:
    """argparse type: a directory to write into (existing, or creatable: no file in the way)."""
    return PathArg("out_dir")


def new_dir() -> PathArg:
    """argparse type: a directory to create, or an empty existing one (a run's --out)."""
    return PathArg("new_dir")


def out_file(make_parents: bool = False) -> PathArg:
    """argparse type: a file to write, in an existing directory (overwriting is the command's call);
    `make_parents`: or in one the command creates (no file in the way)."""
    return PathArg("out_file_tree" if make_parents else "out_file")


def run_dir() -> PathArg:
    """argparse type: a recorded run (a directory with run.json)."""
    return existing_dir("run.json", "a run directory")


# --- run.json metadata ---------------------------------------------------------------------------

_NUMBER = (int, float)
_OBJECT_FIELDS: dict[str, tuple[type, ...]] = {
    "name": (str,),
    "shape": (str,),
    "size_m": (list,),
    "young_pa": _NUMBER,
    "poisson": _NUMBER,
    "damping": _NUMBER,
    "density_kg_m3": _NUMBER,
    "resolution": (int,),
    "dof": (str,),
    "friction": _NUMBER,
}
_METADATA_FIELDS: dict[str, tuple[type, ...]] = {
    "backend": (str,),
    "experiment": (dict, str),
    "duration_s": _NUMBER,
    "seed": (int, type(None)),
    "phases": (list,),
    "object": (dict, type(None)),
    "stereo_truth": (dict, type(None)),
    "calibration_files": (dict, type(None)),
}


def _typed_value(value: object, kinds: tuple[type, ...], where: str) -> None:
    """ConfigError naming `where` unless value is one of kinds (a bool is no number; numbers finite)."""
    ok = isinstance(value, kinds) and not (isinstance(value, bool) and bool not in kinds)
    if ok and isinstance(value, float) and not math.isfinite(value):
        ok = False
    if not ok:
        names = " or ".join(
            "null" if k is type(None) else {dict: "table", list: "list"}.get(k, k.__name__) for k in kinds
        )
        raise ConfigError(f"{where}: expected {names}, got {value!r:.60}")


def check_run_metadata(info: object, run_json: Path | str) -> dict:
    """run.json's metadata, checked to have the types the analyses read (object, experiment, phases,
    duration, seed, backend); ConfigError names the file and the key otherwise."""
    where = f"{run_json}: metadata"
    meta = info.get("metadata", {}) if isinstance(info, dict) else None
    _typed_value(meta, (dict,), where)
    for key, kinds in _METADATA_FIELDS.items():
        if key in meta:
            _typed_value(meta[key], kinds, f"{where}.{key}")
    obj = meta.get("object")
    if isinstance(obj, dict):
        for key, kinds in _OBJECT_FIELDS.items():
            if key in obj:
                _typed_value(obj[key], kinds, f"{where}.object.{key}")
        for k, extent in enumerate(obj.get("size_m", [])):
            _typed_value(extent, _NUMBER, f"{where}.object.size_m[{k}]")
    for k, phase in enumerate(meta.get("phases", [])):
        _typed_value(phase, (str,), f"{where}.phases[{k}]")
    experiment = meta.get("experiment")
    if isinstance(experiment, dict):
        _typed_value(experiment.get("name", ""), (str,), f"{where}.experiment.name")
        _typed_value(experiment.get("object"), (str, type(None)), f"{where}.experiment.object")
        profile = experiment.get("profile", {})
        _typed_value(profile, (dict,), f"{where}.experiment.profile")
        for key, value in profile.items():
            if key.endswith(("_hz", "_s", "_counts", "_nm", "_counts_s")):  # a number, or one per finger
                _typed_value(value, (*_NUMBER, list), f"{where}.experiment.profile.{key}")
                for k, item in enumerate(value if isinstance(value, list) else []):
                    _typed_value(item, _NUMBER, f"{where}.experiment.profile.{key}[{k}]")
        if "frequency_hz" in profile:  # analyses divide by it
            check_number(
                profile["frequency_hz"],
                f"{where}.experiment.profile.frequency_hz",
                min=0.0,
                min_inclusive=False,
            )
    return meta


def experiment_name(meta: dict) -> str | None:
    """The experiment a run's (checked) metadata names: 'compress', 'free', ... (None: unnamed)."""
    experiment = meta.get("experiment")
    return experiment.get("name") if isinstance(experiment, dict) else experiment
