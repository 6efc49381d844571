"""`twin ... --help` says what every option does and what it is when not given; `twin view`'s ports.

The walk goes through the real parser (twin.cli.build_parser), every subcommand and option, and reads
each option's line as argparse formats it."""

import argparse
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from twin.cli import build_parser, main


def _walk(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ("twin",)
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser, argparse.Action]]:
    """(command path, its parser, action) for every argument of every (sub)parser."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:  # the command list `twin --help` prints
                yield path, parser, choice
            for name, sub in action.choices.items():
                yield from _walk(sub, (*path, name))
        elif not isinstance(action, argparse._HelpAction | argparse._VersionAction):
            yield path, parser, action


def _shown_forms(default: object) -> set[str]:
    """How a default may read in a help line: `a b` for a list, 3 or 3.0 for a float 3.0."""
    if isinstance(default, list | tuple):
        return {
            " ".join(str(v) for v in default),
            " ".join(f"{v:g}" for v in default if isinstance(v, float)),
        }
    if isinstance(default, float):
        return {str(default), f"{default:g}"}
    return {str(default)}


ACTIONS = list(_walk(build_parser()))


def _name(path: tuple[str, ...], action: argparse.Action) -> str:
    return " ".join(path) + " " + ("/".join(action.option_strings) or action.metavar or action.dest)


def test_every_option_and_command_has_help():
    missing = [
        _name(p, a) for p, _, a in ACTIONS if not (a.help or "").strip() or a.help == argparse.SUPPRESS
    ]
    assert len(ACTIONS) > 100 and missing == []


def test_every_default_is_shown_in_help():
    checked, hidden = 0, []
    for path, parser, action in ACTIONS:
        default = action.default
        if not action.option_strings or action.nargs == 0 or default in (None, False, argparse.SUPPRESS):
            continue  # positionals, flags, and options whose absence the help describes in words
        if not action.help:  # argparse prints no line, so no default, for an option without help
            hidden.append(f"{_name(path, action)}: default {default!r}, no help line")
            continue
        line = " ".join(parser._get_formatter()._expand_help(action).split())
        printed = " ".join(parser.format_help().split())
        checked += 1
        if line not in printed or not any(form in line for form in _shown_forms(default)):
            hidden.append(f"{_name(path, action)}: default {default!r} not in {line!r}")
    assert checked > 20 and hidden == []


def test_the_known_hidden_defaults_are_shown():
    """The ones the issue found hidden (issue 40): each reads in its command's --help."""
    parser = build_parser()
    sub = parser._subparsers._group_actions[0].choices
    for command, expected in [
        ("train", "full-batch training epochs of every network trained (default: 3000)"),
        ("train", "the folds' shuffle (default: 0)"),
        ("sweep", "processes on this machine, or a Ray cluster (default: local)"),
        ("sweep", "the same seed gives the same dataset (default: 0)"),
        ("sweep", "library objects (default: sphere)"),
        ("identify", "fitted in eq. 4 (default: kelvin-voigt)"),
        ("view", "(default: 9876)"),
        ("view", "(default: 9090)"),
    ]:
        assert expected in " ".join(sub[command].format_help().split()), (command, expected)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("", 0))
        return s.getsockname()[1]


@pytest.fixture
def headless(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


@pytest.fixture
def fake_run(tmp_path: Path) -> Path:
    """A directory with a run.rrd: enough for `twin view` to get to its ports (the file is read after)."""
    (tmp_path / "run.rrd").write_bytes(b"")
    return tmp_path


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--port", "0"], "--port"),
        (["--web-viewer-port", "65536"], "--web-viewer-port"),
        (["--port", "http"], "--port"),
    ],
)
def test_view_refuses_a_bad_port_in_one_line(fake_run: Path, capsys: pytest.CaptureFixture, argv, says):
    assert main(["view", str(fake_run), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("twin: error: ") and err.count("\n") == 1 and says in err


@pytest.mark.parametrize("flag", ["--port", "--web-viewer-port"])
def test_view_headless_refuses_a_taken_port_in_one_line(
    fake_run: Path, headless: None, capsys: pytest.CaptureFixture, flag: str
):
    with socket.socket() as taken:
        taken.bind(("", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["view", str(fake_run), flag, str(port)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert (
        captured.err
        == f"twin: error: port {port} is in use on this machine: pick a free one with {flag} PORT\n"
    )


def test_view_headless_refuses_one_port_for_both(
    fake_run: Path, headless: None, capsys: pytest.CaptureFixture
):
    port = str(_free_port())
    assert main(["view", str(fake_run), "--port", port, "--web-viewer-port", port]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"both {port}" in err
