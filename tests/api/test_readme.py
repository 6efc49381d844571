"""The README's "Use it from Python" and "Learning" examples run as written (in a scratch directory),
and leave the runs, the dataset and the tables they promise."""

import json
import re
from pathlib import Path

import pytest

import twin

README = Path(__file__).resolve().parents[2] / "README.md"


def _examples(section: str) -> str:
    text = README.read_text()
    body = text.split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", body, flags=re.S)
    assert blocks, f"no python example under '{section}'"
    return "\n".join(blocks)


@pytest.mark.xdist_group("realtime")  # one example drives the emulated hand on wall time
def test_the_readme_python_and_learning_examples_run(tmp_path: Path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    exec(compile(_examples("Use it from Python"), "README: Use it from Python", "exec"), {})
    assert capsys.readouterr().out.startswith("complete 61 ")
    for name in ("mine", "squeeze", "mine-hw"):
        assert twin.open_run(tmp_path / "runs" / name).status == "complete"
    exec(compile(_examples("Learning"), "README: Learning", "exec"), {})
    assert "(162,)" in capsys.readouterr().out
    info = json.loads((tmp_path / "datasets/squeeze/meta/info.json").read_text())
    assert info["total_episodes"] == 2 and "observation.environment_state" in info["features"]
    assert (tmp_path / "tables/squeeze/hand.parquet").is_file()
