"""One namespace (issue 40): the repository's hardware/, experiments/ and models/barrett_mjcf/ install as
twin.hardware, twin.experiments and twin/models/barrett_mjcf, and nothing imports them by their old
top-level names (which the tests' own sys.path, the checkout's root, would still resolve). The wheel itself
is tests/packaging/test_wheel.py; ruff's TID251 (pyproject.toml) bans the old names in .py files."""

import json
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SETUPTOOLS = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
OLD_IMPORT = re.compile(r"^\s*(from|import)\s+(hardware|experiments|models)\b", re.M)


def _source_dir(package: str) -> Path:
    """Where setuptools takes `package` from: the longest package-dir mapping that prefixes it."""
    mapped = [p for p in SETUPTOOLS["package-dir"] if package == p or package.startswith(p + ".")]
    if not mapped:
        return ROOT.joinpath(*package.split("."))
    base = max(mapped, key=len)
    rest = package[len(base) :].strip(".").split(".")
    return ROOT.joinpath(SETUPTOOLS["package-dir"][base], *filter(None, rest))


def test_the_package_list_names_every_package_on_disk_and_only_those():
    listed = set(SETUPTOOLS["packages"])
    assert all(p == "twin" or p.startswith("twin.") for p in listed)
    on_disk = set()
    for top, name in (("twin", "twin"), ("hardware", "twin.hardware"), ("experiments", "twin.experiments")):
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top).parts
            on_disk.add(".".join((name, *rel)))
    assert on_disk <= listed, f"packages missing from pyproject.toml: {sorted(on_disk - listed)}"
    for package in listed:
        where = _source_dir(package)
        assert where.is_dir(), (package, where)
        assert (where / "__init__.py").is_file() or package == "twin.models.barrett_mjcf", package
    assert _source_dir("twin.models.barrett_mjcf") == ROOT / "models" / "barrett_mjcf"


def test_the_notebooks_import_no_old_top_level_name():
    for notebook in sorted((ROOT / "notebooks").glob("*.ipynb")):
        cells = json.loads(notebook.read_text())["cells"]
        code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
        assert not OLD_IMPORT.search(code), (notebook.name, OLD_IMPORT.search(code))


def test_the_installed_names_resolve_outside_the_checkout_and_the_old_ones_do_not(tmp_path: Path):
    """How CI installs (`pip install -e`): setuptools' editable finder maps twin.hardware and
    twin.experiments onto the checkout's folders and adds no top-level name; a wheel does the same."""
    code = (
        "import importlib, json\n"
        "import twin.experiments.compress, twin.hardware.backend, twin.hardware.bh262.urlhandler\n"
        "from twin.assets import HAND_XML, SCENE_XML\n"
        "found = {}\n"
        "for name in ('hardware', 'experiments', 'models'):\n"
        "    try:\n"
        "        importlib.import_module(name)\n"
        "        found[name] = True\n"
        "    except ModuleNotFoundError:\n"
        "        found[name] = False\n"
        "print(json.dumps([HAND_XML.is_file(), SCENE_XML.is_file(), found]))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env, check=False
    )
    assert result.returncode == 0, result.stderr
    hand, scene, found = json.loads(result.stdout)
    assert hand and scene
    assert found == {"hardware": False, "experiments": False, "models": False}
