"""Every command in README.md and the docs runs as written, in a scratch directory, and does what the page
says: each fenced ```bash block line by line through bash, each ```python block exec'd in one namespace
per page, in page order (later examples use the runs of earlier ones).

A command or block the suite does not run carries its reason in the page itself: a comment line
`# not run by the suite: REASON` before the command, or `<!-- not run by the suite: REASON -->` just
before the block. Those are listed here (NOT_RUN) and the inventory test fails on any change, so
nothing is left out silently. A command whose comment says `until Ctrl-C` (a server, such as the
emulated rig) is started in the background; the page's later blocks run against it, then it gets
SIGINT and must stop by itself. Blocks of other languages (```text: output, trees; ```sql) hold no
shell or Python command."""

import json
import os
import re
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import pytest

import twin

ROOT = Path(__file__).resolve().parents[2]
PAGES = [
    ROOT / "README.md",
    *sorted((ROOT / "docs").glob("*.md")),
    ROOT / "hardware" / "README.md",
    ROOT / "models" / "barrett_mjcf" / "README.md",
]
MARK = "not run by the suite: "
BLOCK = re.compile(
    r"(?:^<!-- (?P<mark>not run by the suite: .*?) -->\n)?^```(?P<lang>[^\n`]*)\n(?P<body>.*?)^```$",
    re.M | re.S,
)
LANGUAGES = {"bash", "python", "text", "sql"}
COMMAND_START = re.compile(r"^\s*(twin|python3?|pip|\.venv/bin/|source) ")

# Every command the suite does not run: page -> [(its first line as written, start of its stated reason)].
NOT_RUN = {
    "README.md": [
        (
            "python3 -m venv .venv && .venv/bin/pip install -e '.[all]' && .venv/bin/twin run compress "
            "--object block --duration 10",
            "it creates .venv and installs the package",
        ),
        (
            "python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && .venv/bin/ruff check . && "
            ".venv/bin/ruff format --check . && .venv/bin/pytest -n 2",
            "it is the suite",
        ),
    ],
    "docs/api.md": [
        ("import os", "here; tests/envs/test_normalized.py runs it as written for 256 steps"),
        (".venv/bin/python -m tests.export.lerobot_env", "it downloads ~155 MB and takes minutes"),
        (
            "python3 -m venv lerobot-env && lerobot-env/bin/pip install -r "
            "tests/export/lerobot_env/requirements.txt \\",
            "it downloads ~155 MB and takes minutes",
        ),
        (
            "from lerobot.datasets.lerobot_dataset import LeRobotDataset",
            "lerobot cannot share this environment",
        ),
        (
            "python3 -m venv lerobot-full && lerobot-full/bin/pip install lerobot==0.4.4",
            "4.35 GB of downloads",
        ),
        (
            "TWIN_LEROBOT_PYTHON=lerobot-full/bin/python .venv/bin/pytest -n 0 tests/export -m network",
            "4.35 GB of downloads",
        ),
        ("SELECT decode(key) AS key, decode(value) AS value", "DuckDB is not a dependency"),
        ("SELECT h.t_s, h.position_counts, c.t_s AS sent_s, c.position_counts AS set_point", "DuckDB is not"),
    ],
    "docs/cli.md": [
        ("twin identify runs/sphere --free runs/free", "minutes of simulations"),
        ("twin fit runs/sphere", "minutes of replays"),
    ],
    "docs/overview.md": [('.venv/bin/pytest -n 2 -m "not slow"', "it is the suite")],
    "docs/shape_network.md": [
        (
            "twin sweep --objects cylinder block --trajectories 24 --duration 20 --workers 2 "
            "--out data/shape",
            "the benchmark's sweep",
        ),
        ("twin sweep ... --executor ray", "the benchmark's sweep"),
        ("twin sweep ... --executor ray --address HOST:6379", "the benchmark's sweep"),
        *(
            (f"twin train data/shape --object {rest}", "it trains on the sweep above")
            for rest in (
                "cylinder",
                "cylinder --target largest",
                "cylinder --folds 6",
                "cylinder --validation 0.25",
                "block --target surface",
            )
        ),
    ],
    "docs/viewing.md": [
        (
            "python -m twin.viz.screenshots RUN_DIR [RUN_DIR ...] --out DIR [--at S] [--max-size PX]",
            "a synopsis",
        )
    ],
    "hardware/README.md": [
        ("apt-get install libboost-dev libpoco-dev", "it needs the two clients' sources"),
        (
            ".venv/bin/python tools/third_party_clients/build_and_run.py \\",
            "it needs the two clients' sources",
        ),
    ],
}


@dataclass
class Command:
    page: str
    lang: str
    text: str  # as written (a shell command without its trailing comment; a Python block whole)
    reason: str | None  # why the suite does not run it; None: it runs
    background: bool = False  # a server: runs until Ctrl-C while the page's later blocks run


def _strip_comment(line: str) -> str:
    return re.sub(r"\s+#\s.*$", "", line)


def commands(page: Path) -> list[Command]:
    """The page's commands in page order; raises on a fence without a known language."""
    name = page.relative_to(ROOT).as_posix()
    found = []
    for block in BLOCK.finditer(page.read_text()):
        lang, body = block["lang"].strip(), block["body"]
        assert lang in LANGUAGES, f"{name}: a fenced block without a known language ({lang!r}): {body[:60]!r}"
        block_reason = block["mark"][len(MARK) :] if block["mark"] else None
        if lang in ("python", "sql"):
            found.append(Command(name, lang, body.rstrip("\n"), block_reason))
            continue
        if lang == "text":
            for line in body.splitlines():
                assert not COMMAND_START.match(line), f"{name}: a command in a text block: {line}"
            continue
        reason = block_reason
        for line in re.sub(r"\\\n", "\\\\\x00", body).splitlines():
            line = line.replace("\\\x00", "\\\n")
            if not line.strip():
                continue
            if line.lstrip().startswith("#"):
                if MARK in line:
                    reason = line.split(MARK, 1)[1]
                continue
            found.append(Command(name, "bash", _strip_comment(line), reason, "until Ctrl-C" in line))
            reason = block_reason
    return found


def _scratch(tmp_path: Path) -> dict[str, str]:
    """tmp_path as a fresh clone on a headless machine sees it: .venv is this interpreter's environment,
    its bin on PATH."""
    prefix = Path(sys.prefix)
    assert (prefix / "bin" / "activate").is_file(), f"the suite runs in a virtual environment, not {prefix}"
    (tmp_path / ".venv").symlink_to(prefix)
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}  # headless
    return {**env, "PATH": f"{prefix / 'bin'}{os.pathsep}{os.environ['PATH']}"}


class Server:
    """A command that serves until Ctrl-C: started, ready when it prints `ready`, then SIGINT."""

    def __init__(self, command: str, cwd: Path, env: dict[str, str]):
        self.command = command
        self.proc = subprocess.Popen(
            ["bash", "-c", f"exec {command}"],
            cwd=cwd,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.out: list[str] = []
        self.ready = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()
        self.ready.wait(timeout=180)
        assert self.ready.is_set(), f"{command}: not ready in 180 s:\n{''.join(self.out)}"

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.out.append(line)
            if "ready" in line:
                self.ready.set()
        self.ready.set()  # ended: the assertion above reads what it printed

    def stop(self) -> str:
        self.proc.send_signal(signal.SIGINT)
        code = self.proc.wait(timeout=60)
        assert code in (0, 130), f"{self.command}: exit {code} after Ctrl-C:\n{''.join(self.out)}"
        return "".join(self.out)


def run_page(page: str, tmp_path: Path) -> dict[str, str]:
    """Every runnable command of the page, in order, in tmp_path; returns each shell command's output."""
    env = _scratch(tmp_path)
    outputs: dict[str, str] = {}
    servers: list[Server] = []
    scope: dict = {}
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        for cmd in commands(ROOT / page):
            if cmd.reason is not None:
                continue
            if cmd.lang == "python":
                exec(compile(cmd.text, f"{page}: python block", "exec"), scope)
            elif cmd.background:
                servers.append(Server(cmd.text, tmp_path, env))
            else:
                done = subprocess.run(
                    ["bash", "-c", cmd.text],
                    cwd=tmp_path,
                    env=env,
                    capture_output=True,
                    text=True,
                    timeout=600,
                )
                assert done.returncode == 0, (
                    f"{page}: `{cmd.text}` exit {done.returncode}:\n{done.stderr[-3000:]}"
                )
                outputs[cmd.text] = done.stdout + done.stderr
    finally:
        os.chdir(cwd)
        for server in servers:
            outputs[server.command] = server.stop()
    return outputs


def _status(run_dir: Path) -> str:
    return json.loads((run_dir / "run.json").read_text())["status"]


def test_every_command_in_the_docs_is_run_or_says_why_not():
    not_run: dict[str, list[tuple[str, str]]] = {}
    runs = []
    for page in PAGES:
        for cmd in commands(page):
            if cmd.reason is None:
                runs.append(cmd)
            else:
                not_run.setdefault(cmd.page, []).append((cmd.text.splitlines()[0], cmd.reason))
    assert {p: [c for c, _ in cs] for p, cs in not_run.items()} == {
        p: [c for c, _ in cs] for p, cs in NOT_RUN.items()
    }
    for page, listed in NOT_RUN.items():
        for (_, reason), (_, start) in zip(not_run[page], listed, strict=True):
            assert reason.startswith(start), (page, reason)
    assert sum(map(len, NOT_RUN.values())) == 24
    # the pages whose commands run, each by a test below
    assert {c.page for c in runs} == {"README.md", "docs/cli.md", "docs/api.md"}
    assert len(runs) == 24


@pytest.mark.slow
def test_the_readme_quick_start_runs_as_written(tmp_path: Path):
    out = run_page("README.md", tmp_path)
    assert out["twin --version"].strip() == f"twin {twin.__version__}"
    assert "block" in out["twin objects"] and "sphere" in out["twin objects"]
    assert "run complete" in out["twin run compress --object block --duration 10 --out runs/block"]
    assert _status(tmp_path / "runs" / "block") == "complete"
    assert "complete" in out["twin info runs/block"]
    assert "runs/block/run.rrd" in out["twin view runs/block"]  # headless: how to open it in a browser


@pytest.mark.slow
def test_the_command_examples_run_as_written(tmp_path: Path):
    out = run_page("docs/cli.md", tmp_path)
    for name in ("firm", "sphere", "free", "hw", "sim"):
        assert _status(tmp_path / "runs" / name) == "complete", name
    assert json.loads((tmp_path / "runs/firm/run.json").read_text())["metadata"]["seed"] == 2
    (other,) = (tmp_path / "runs").glob("compress-block-*")  # the run without --out
    assert _status(other) == "complete"
    assert (tmp_path / "runs/emu/rig.toml").is_file()
    assert "ready" in out["twin emulate rig --rig-file runs/emu/rig.toml"]
    compared = out["twin run compress --duration 10 --out runs/sim && twin compare runs/sim runs/hw"]
    assert "run complete: runs/sim" in compared and "% of travel" in compared  # the sim against the hardware


@pytest.mark.slow
def test_the_python_api_examples_run_as_written(tmp_path: Path, capsys):
    run_page("docs/api.md", tmp_path)
    printed = capsys.readouterr().out
    assert printed.startswith("complete 61 ")  # A first script: 2 s at 30 Hz, both ends
    assert "(162,)" in printed  # the Learning example's tactile observation
    for name in ("mine", "squeeze", "mine-hw", "touch-sim", "touch-hw", "hw-compress"):
        assert twin.open_run(tmp_path / "runs" / name).status == "complete", name
    info = json.loads((tmp_path / "datasets/squeeze/meta/info.json").read_text())
    assert info["total_episodes"] == 2 and "observation.environment_state" in info["features"]
    assert (tmp_path / "tables/squeeze/hand.parquet").is_file()


LINK = re.compile(r"\]\((?P<target>[^)\s]+)\)")


def _anchors(page: Path) -> set[str]:
    """The heading anchors GitHub gives a Markdown page (lower case, punctuation dropped, spaces to -)."""
    text = re.sub(r"^```.*?^```$", "", page.read_text(), flags=re.M | re.S)
    titles = re.findall(r"^#{1,6} (.+)$", text, flags=re.M)
    return {re.sub(r"[^\w\- ]", "", t.strip().lower()).replace(" ", "-") for t in titles}


def test_every_link_in_the_readme_and_docs_leads_to_a_file_and_heading():
    for page in PAGES:
        for link in LINK.finditer(page.read_text()):
            target = link["target"]
            if target.startswith(("http://", "https://")):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            assert file.exists(), f"{page.relative_to(ROOT)}: {target} leads nowhere"
            assert not anchor or anchor in _anchors(file), f"{page.relative_to(ROOT)}: no heading #{anchor}"


def test_the_readme_reaches_docs_early_and_keeps_the_set_up_commands_of_ci():
    lines = (ROOT / "README.md").read_text().splitlines()
    first = next(n for n, line in enumerate(lines, 1) if "](docs/" in line)
    assert first <= 150
    bash = [c.text for c in commands(ROOT / "README.md") if c.lang == "bash"]
    assert bash[1] in (ROOT / ".ci" / "run").read_text()  # the README's test command is what CI runs
    assert bash[0].startswith("python3 -m venv .venv && .venv/bin/pip install -e '.[all]' && ")
