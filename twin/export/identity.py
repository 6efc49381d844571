"""Which run a row of an export came from, without the user's filesystem path.

`run_id(run)`: run.json's `run_id` (a UUID the writer draws, kept wherever the directory is copied);
runs written before it existed get one derived from what their run.json recorded at creation.
`run_names(paths)`: each run's directory relative to the deepest folder holding them all (`a/r` and
`b/r` stay apart; one run alone is its directory's name): what an export says where it says "run".
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from twin.recording import Run


def run_id(run: Run) -> str:
    """The run's id: run.json's `run_id`, else `sha256:` and a digest of its creation record."""
    identity = run.info.get("run_id")
    if isinstance(identity, str) and identity:
        return identity
    record = {key: run.info.get(key) for key in ("created_utc", "metadata", "streams", "writer")}
    digest = hashlib.sha256(json.dumps(record, sort_keys=True, default=str).encode()).hexdigest()
    return f"sha256:{digest[:32]}"


def run_names(paths: list[Path]) -> list[str]:
    """Each run directory relative to the deepest folder that holds them all (POSIX separators)."""
    resolved = [Path(p).resolve() for p in paths]
    if len(resolved) == 1:
        return [resolved[0].name]
    common = Path(os.path.commonpath(resolved))
    return [p.relative_to(common).as_posix() if p != common else p.name for p in resolved]
