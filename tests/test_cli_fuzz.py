"""A Hypothesis fuzzer over every `twin` subcommand's numeric and path arguments.

Every case is bad input (nan, +-inf, 1e309, out of range, not a number, empty or NUL paths, missing
paths, a file where a directory belongs, unicode names, wrong-typed run.json) and must end the house's
way: exit status 2, exactly one line on stderr starting `twin: error:`, no traceback, nothing written.
The cases call `twin.cli.main` in-process (a subprocess per case would cost ~1 s each); a few run the
console script itself. The flags are found by walking the real parser, so a numeric or path flag added
later is fuzzed (or, if it skips the shared validator, fails the census test below).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from twin.cli import build_parser, main
from twin.validation import NumberArg, PathArg

CASES: Counter[str] = Counter()
"""Cases run, per kind."""
NUMBER_CASES, PATH_CASES = 1200, 900
"""Fuzz cases per run: 2,100 in all (each test asserts its own share ran)."""

# Each subcommand with its required arguments filled in validly: (positionals by dest, options). The
# fuzzed argument replaces its positional, or follows as --flag=VALUE.
BASE: dict[tuple[str, ...], tuple[dict[str, str], list[str]]] = {
    ("run", "compress"): ({}, []),
    ("run", "free"): ({}, []),
    ("identify",): ({"run_dir": "RUN"}, []),
    ("fit",): ({"run_dir": "RUN"}, []),
    ("sweep",): ({}, ["--out", "new_dataset"]),
    ("train",): ({"dataset": "DATASET"}, ["--object", "block"]),
    ("emulate",): ({"what": "hand"}, []),
    ("info",): ({"run_dir": "RUN"}, []),
    ("compare",): ({"run_a": "RUN", "run_b": "RUN"}, []),
    ("view",): ({"run_dir": "RUN"}, []),
    ("calibrate", "cameras"): ({}, []),
    ("objects",): ({}, []),
    ("export",): ({"runs": "RUN"}, ["--out", "new_export"]),
}


def _argv(path: tuple[str, ...], replace: str | None = None, bad: str = "") -> list[str]:
    """The subcommand's valid base command line, with positional `replace` set to `bad`."""
    positionals, options = BASE[path]
    return [*path, *(bad if dest == replace else v for dest, v in positionals.items()), *options]


def _walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> Iterator[tuple]:
    """(subcommand path, action) for every argument of every (sub)parser."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _walk(sub, (*path, name))
        else:
            yield path, action


ACTIONS = list(_walk(build_parser()))
NUMBERS = [(p, a) for p, a in ACTIONS if isinstance(a.type, NumberArg)]
PATHS = [(p, a) for p, a in ACTIONS if isinstance(a.type, PathArg)]


def _sample_run_json(**metadata: object) -> str:
    """A run.json the reader accepts (no streams), with the given metadata."""
    meta = {"experiment": {"name": "compress", "object": "block", "profile": {}}, **metadata}
    info = {"format": "barrett-twin-run", "format_version": 1, "status": "complete", "streams": {}}
    return json.dumps({**info, "metadata": meta})


@pytest.fixture(scope="module")
def workdir() -> Iterator[Path]:
    """A scratch cwd with what valid companions of a bad argument need: a run, a dataset, a model
    directory, a rig file, a plain file and an empty directory. The cwd moves there for the module."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "RUN").mkdir()
        (root / "RUN" / "run.json").write_text(_sample_run_json())
        (root / "FREE").mkdir()
        (root / "FREE" / "run.json").write_text(_sample_run_json(experiment={"name": "free"}))
        (root / "DATASET").mkdir()
        (root / "DATASET" / "index.json").write_text('{"trajectories": []}')
        (root / "MODEL").mkdir()
        (root / "file").write_text("x")
        (root / "rig.toml").write_text("")
        (root / "empty_dir").mkdir()
        (root / "full_dir").mkdir()
        (root / "full_dir" / "keep").write_text("x")
        (root / "taken.json").write_text("{}")
        cwd = Path.cwd()
        os.chdir(root)
        try:
            yield root
        finally:
            os.chdir(cwd)


def _listing(root: Path) -> list[tuple[str, int, int]]:
    """Every path under root with its size and mtime: what 'nothing written' compares."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        for name in sorted(dirnames + filenames):
            st_ = os.lstat(os.path.join(dirpath, name))
            out.append((os.path.join(dirpath, name), st_.st_size, st_.st_mtime_ns))
    return sorted(out)


def assert_refused(argv: list[str], root: Path, test: str) -> str:
    """Run `twin ARGV` in-process: exit 2, one `twin: error:` line, no traceback, nothing written."""
    before = _listing(root)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    lines = err.getvalue().splitlines()
    shown = f"twin {argv!r}\nstdout: {out.getvalue()!r}\nstderr: {err.getvalue()!r}"
    assert code == 2, shown
    assert len(lines) == 1 and lines[0].startswith("twin: error:"), shown
    assert "Traceback" not in out.getvalue() + err.getvalue(), shown
    assert _listing(root) == before, shown
    CASES[test] += 1
    return lines[0]


# --- bad numbers ---------------------------------------------------------------------------------

NOT_NUMBERS = st.sampled_from(
    ["nan", "NaN", "-nan", "inf", "-inf", "+inf", "Infinity", "1e309", "-1e309", "", " ", "x", "1,5",
     "0x10", "1e", "--", "½", "١e999",
     # numbers Python's int() and float() take that are not plain ASCII decimals (issue 37)
     "0_5", "1_0", "٥", "۵", "５", "５.０", "𝟓", " 5", "5 ", "\u00a05", "5\t"]
)  # fmt: skip


def _outside(number: NumberArg) -> st.SearchStrategy[str]:
    """Text of numbers outside the flag's range (and, for an integer flag, numbers that are not one)."""
    r = number.range
    parts = []
    if r.kind is int:
        if r.min is not None:
            parts.append(st.integers(max_value=int(r.min) - 1))
        if r.max is not None:
            parts.append(st.integers(min_value=int(r.max) + 1))
        parts.append(st.floats(allow_nan=False, allow_infinity=False).map(lambda v: f"{v:.3f}"))
        return st.one_of(*parts).map(str)
    if r.min is not None:
        parts.append(st.floats(max_value=r.min, exclude_max=r.min_inclusive, allow_infinity=False))
    if r.max is not None:
        parts.append(st.floats(min_value=r.max, exclude_min=r.max_inclusive, allow_infinity=False))
    parts.append(st.sampled_from([1e308, -1e308, 5e-324, -0.0] if r.min == 0 else [1e308, -1e308]))
    return st.one_of(*parts).filter(lambda v: not r.contains(v)).map(repr)


@st.composite
def number_cases(draw: st.DrawFn) -> list[str]:
    path, action = draw(st.sampled_from(NUMBERS))
    flag = action.option_strings[-1]
    value = draw(st.one_of(NOT_NUMBERS, _outside(action.type)))
    if action.nargs == 3:  # --size-mm X Y Z: one bad extent among good ones ('-inf' reads as an option)
        values = ["50", "50", "50"]
        values[draw(st.integers(0, 2))] = value
        return [*_argv(path), flag, *values]
    return [*_argv(path), f"{flag}={value}"]


def fuzz(test: str, examples: int, strategy: st.SearchStrategy, check) -> int:
    """Run `check` on `examples` derandomized draws of `strategy`; the cases it ran (>= examples)."""
    before = CASES[test]

    @settings(
        max_examples=examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    )
    @given(strategy)
    def run(case: object) -> None:
        check(case)

    run()
    cases = CASES[test] - before
    print(f"\n{test}: {cases} CLI fuzz cases")
    return cases


@pytest.mark.slow
def test_bad_numbers_are_refused_in_one_line(workdir: Path, record_property):
    def check(argv: list[str]) -> None:
        line = assert_refused(argv, workdir, "numbers")
        if "=" in argv[-1]:  # the validator's own message, naming the flag
            assert argv[-1].split("=")[0] in line, line

    cases = fuzz("numbers", NUMBER_CASES, number_cases(), check)
    record_property("cases", cases)
    assert cases >= NUMBER_CASES


# --- bad paths -----------------------------------------------------------------------------------

NAMES = st.text(
    st.characters(blacklist_categories=("Cs",), blacklist_characters="\0/"), min_size=1, max_size=30
).filter(lambda s: s not in (".", ".."))

BAD_PATHS = {
    "dir": ["", "a\0b", "file", "file/x", "missing", "missing/deeper", "rig.toml", "x" * 300],
    "file": ["", "a\0b", "empty_dir", "missing.toml", "file/x", "x" * 300],
    "out_dir": ["", "a\0b", "file", "file/x", "file/x/y", "rig.toml"],
    "new_dir": ["", "a\0b", "file", "file/x", "full_dir", "RUN"],
    "out_file": ["", "a\0b", "empty_dir", "RUN", "missing_dir/x.json", "file/x.json"],
    "out_file_tree": ["", "a\0b", "empty_dir", "RUN", "file/x.json", "file/x/y.toml"],
}


@st.composite
def path_cases(draw: st.DrawFn) -> list[str]:
    path, action = draw(st.sampled_from(PATHS))
    role = action.type.role
    bad_paths = BAD_PATHS[role] + (["empty_dir", "MODEL"] if role == "dir" and action.type.contains else [])
    if role in ("dir", "file"):
        generated = NAMES.map(lambda n: f"missing_{n}")  # nothing by that name
    else:
        generated = NAMES.map(lambda n: f"file/{n}")  # under a plain file: can never be created
    bad = draw(st.one_of(st.sampled_from(bad_paths), generated))
    if not action.option_strings:  # a positional: in place of the valid one
        return _argv(path, action.dest, bad)
    if action.nargs == "+":
        return [*_argv(path), action.option_strings[-1], "RUN", bad]
    return [*_argv(path), f"{action.option_strings[-1]}={bad}"]


@pytest.mark.slow
def test_bad_paths_are_refused_in_one_line(workdir: Path, record_property):
    cases = fuzz("paths", PATH_CASES, path_cases(), lambda a: assert_refused(a, workdir, "paths"))
    record_property("cases", cases)
    assert cases >= PATH_CASES


# --- inputs that pass argparse but not the command's own checks ---------------------------------

SEMANTIC = [
    ["fit", "RUN", "--object", "pillow"],
    ["fit", "RUN", "--size-mm", "60", "60", "70"],
    ["fit", "RUN", "--object", "block", "--size-mm", "200", "200", "50"],
    ["identify", "RUN", "--free", "RUN"],
    ["identify", "RUN", "--shape", "block"],
    ["identify", "RUN", "--size-mm", "60", "60", "70"],
    ["calibrate", "cameras", "--out", "taken.json"],
    ["calibrate", "cameras", "--views", "empty_dir", "--seed", "3"],
    ["emulate", "hand", "--baud", "5"],
    ["emulate", "hand", "--port", "tcp:99999"],
    ["emulate", "hand", "--port", "tcp:١٢"],
    ["emulate", "hand", "--port", "serial"],
    ["run", "compress", "--object", "pillow"],
    ["run", "compress", "--size-mm", "200", "200", "50"],
    ["run", "compress", "--bbox", "1,2,3,4"],
    ["run", "compress", "--hand", "x"],
    ["sweep", "--out", "new_dataset", "--objects", "pillow"],
    ["train", "DATASET", "--object", "block", "--folds", "3", "--validation", "0.5"],
]
BAD_METADATA = [
    {"object": 5},
    {"object": "block"},
    {"object": {"name": 5}},
    {"object": {"size_m": "abc"}},
    {"object": {"size_m": [0.06, "x", 0.07]}},
    {"object": {"young_pa": True}},
    {"duration_s": "x"},
    {"duration_s": None},
    {"seed": 1.5},
    {"phases": "compress"},
    {"phases": [1, 2]},
    {"backend": 3},
    {"experiment": 5},
    {"experiment": {"name": 5}},
    {"experiment": {"name": "compress", "profile": []}},
    {"experiment": {"name": "compress", "profile": {"frequency_hz": 0}}},
    {"experiment": {"name": "compress", "profile": {"frequency_hz": "fast"}}},
    {"stereo_truth": 3},
]


@pytest.mark.parametrize("argv", SEMANTIC, ids=lambda a: " ".join(a)[:50])
def test_bad_combinations_are_refused_before_any_work(workdir: Path, argv: list[str]):
    assert_refused(argv, workdir, "combinations")


@pytest.mark.parametrize("command", ["info", "identify", "fit"])
@pytest.mark.parametrize("metadata", BAD_METADATA, ids=lambda m: json.dumps(m)[:40])
def test_run_json_metadata_of_the_wrong_type_is_named_in_one_line(
    workdir: Path, command: str, metadata: dict
):
    run = workdir / "BAD_RUN"
    run.mkdir(exist_ok=True)
    (run / "run.json").write_text(_sample_run_json(**metadata))
    line = assert_refused([command, "BAD_RUN"], workdir, "metadata")
    key = next(iter(metadata))
    assert f"run.json: metadata.{key}" in line, line


def test_whole_metadata_of_the_wrong_type(workdir: Path):
    run = workdir / "LIST_RUN"
    run.mkdir(exist_ok=True)
    info = json.loads(_sample_run_json())
    info["metadata"] = []
    (run / "run.json").write_text(json.dumps(info))
    for command in ("info", "identify", "fit"):
        assert "run.json: metadata: expected table" in assert_refused(
            [command, "LIST_RUN"], workdir, "metadata"
        )


# --- the census ----------------------------------------------------------------------------------


def test_every_number_and_path_goes_through_the_validator():
    """No flag converts with bare float/int/Path: each is checked by twin.validation (and so fuzzed)."""
    raw = [(p, a.dest) for p, a in ACTIONS if a.type in (float, int, Path, str)]
    assert raw == []
    numeric = {a.dest for _p, a in NUMBERS}
    assert {
        "young",
        "poisson",
        "damping",
        "density",
        "size_mm",
        "resolution",
        "friction",
        "duration",
    } <= numeric
    assert {"seed", "workers", "trajectories", "points", "epochs", "folds", "validation", "baud"} <= numeric
    assert len(NUMBERS) >= 28 and len(PATHS) >= 22, (len(NUMBERS), len(PATHS))


# --- the console script itself -------------------------------------------------------------------

SCRIPT_CASES = [
    ["run", "compress", "--duration", "inf", "--out", "SCRIPT_RUN"],
    ["run", "compress", "--seed", "-1", "--out", "SCRIPT_RUN"],
    ["sweep", "--duration", "nan", "--out", "SCRIPT_DATASET"],
    ["fit", "RUN", "--young", "inf"],
    ["emulate", "hand", "--rig-file", "file/emu/rig.toml"],  # under a plain file: never creatable
]


@pytest.mark.parametrize("argv", SCRIPT_CASES, ids=lambda a: " ".join(a[:3]))
def test_the_console_script_prints_one_line_and_no_traceback(workdir: Path, argv: list[str]):
    twin = Path(sys.executable).with_name("twin")
    command = [str(twin)] if twin.exists() else [sys.executable, "-m", "twin.cli"]
    before = _listing(workdir)
    result = subprocess.run([*command, *argv], cwd=workdir, capture_output=True, text=True, timeout=120)
    lines = result.stderr.splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and lines[0].startswith("twin: error:"), result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    assert _listing(workdir) == before
