"""Run directories: multi-rate streams (Arrow IPC stream files) plus run.json metadata."""

from twin.recording.reader import Run, RunFormatError, StreamData, open_run
from twin.recording.schema import RAGGED, FieldSpec, StreamSpec
from twin.recording.writer import RunWriter

__all__ = [
    "RAGGED",
    "FieldSpec",
    "Run",
    "RunFormatError",
    "RunWriter",
    "StreamData",
    "StreamSpec",
    "open_run",
]
