"""benchmarks/run_all.py rewrites the sections it runs and keeps the rest of BENCHMARKS.md: the other
sections and the notes before the first one."""

from pathlib import Path

from benchmarks.run_all import read_preamble, read_sections


def test_the_notes_before_the_first_section_and_every_section_are_read_back(tmp_path: Path):
    page = tmp_path / "BENCHMARKS.md"
    assert read_preamble(page) == "# Benchmarks\n\n" and read_sections(page) == {}
    notes = "# Benchmarks\n\nThe clutch rule changed: sections before then used the old one.\n\n"
    sections = "<!-- section:a -->\nA's table\n<!-- /section:a -->\n\n"
    sections += "<!-- section:b -->\nB\n<!-- /section:b -->\n"
    page.write_text(notes + sections)
    assert read_preamble(page) == notes
    assert read_sections(page) == {"a": "A's table\n", "b": "B\n"}


def test_every_section_of_benchmarks_md_is_opened_and_closed_once_in_order():
    """A section missing a marker is invisible to read_sections, and run_all drops it on its next write
    (the Poisson section lost its closing marker once, and identify_speed its opening one)."""
    import re

    from benchmarks.run_all import ROOT, SECTIONS

    text = (ROOT / "BENCHMARKS.md").read_text()
    markers = re.findall(r"<!-- (/?)section:(\w+) -->", text)
    opened = [name for slash, name in markers if not slash]
    assert markers == [m for name in opened for m in (("", name), ("/", name))]
    assert len(set(opened)) == len(opened) and set(opened) <= set(SECTIONS)
    assert read_sections(ROOT / "BENCHMARKS.md").keys() == set(opened)
