"""A stand-in for torchvision in the LeRobot side environment (tests/export/lerobot_env), NOT torchvision.

Why: lerobot 0.4.4's dataset code imports torchvision, and the only torchvision wheel on the registry for
the project's torch 2.13.0 (CPU) is a CUDA build that cannot import against it. LeRobot's dataset loader
calls torchvision for two things only, and this holds those two, written here to the behaviour torchvision
0.25.0 (the last release lerobot 0.4.4 accepts) documents, for the calls LeRobot makes: `transforms.ToTensor`
(parquet images -> float CHW in [0, 1]) and, for video datasets decoded with the "pyav" backend (torchcodec
has no CPU build for torch 2.13.0 either), `set_video_backend` and `io.VideoReader`. Besides those, only
names lerobot's modules import on load and the side environment never calls (`transforms.functional`,
`transforms.v2.Transform`, `transforms.v2.functional`: empty, or raising when used); any other use fails.
lerobot's own code is unmodified. The full lerobot install (the real torchvision 0.25) was checked by hand
to hand out bit-identical arrays on the same export, against a first version of this stand-in doing the
same conversions (docs/api.md, Export)."""

from . import io, transforms

__version__ = "0.25.0+stand-in"
_video_backend = "pyav"


def set_video_backend(backend: str) -> None:
    """torchvision's, where "pyav" (PyAV) is the only backend there is."""
    global _video_backend
    if backend != "pyav":
        raise RuntimeError(f"the torchvision stand-in decodes with 'pyav' only, not {backend!r}")
    _video_backend = backend


def get_video_backend() -> str:
    return _video_backend


__all__ = ["get_video_backend", "io", "set_video_backend", "transforms"]
