"""`io.VideoReader` for LeRobot's "pyav" video backend: the frames of one video stream, decoded by PyAV,
written to torchvision's documented interface (not from its code); the stand-in's docstring says why."""

from collections.abc import Iterator
from typing import Any

import av
import torch


class VideoReader:
    """Frames of a file's video stream in order, each {"data": RGB uint8 tensor C x H x W, "pts": s};
    `container` is the PyAV container (LeRobot closes it when done)."""

    def __init__(self, src: str, stream: str = "video", num_threads: int = 0) -> None:
        kind, _, index = stream.partition(":")
        if kind != "video":
            raise ValueError(f"the torchvision stand-in reads video streams only, not {stream!r}")
        self.container = av.open(str(src))
        self._stream = self.container.streams.video[int(index or 0)]
        self._frames = self.container.decode(self._stream)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        return self

    def __next__(self) -> dict[str, Any]:
        frame = next(self._frames)  # StopIteration at the stream's end
        rgb = torch.from_numpy(frame.to_ndarray(format="rgb24")).permute(2, 0, 1)
        return {"data": rgb, "pts": float(frame.pts * frame.time_base)}

    def seek(self, time_s: float, keyframes_only: bool = False) -> "VideoReader":
        """Decode on from the key frame at or before `time_s` (LeRobot passes keyframes_only=True here
        and skips forward itself)."""
        target = max(0, round(time_s / self._stream.time_base))
        self.container.seek(target, stream=self._stream, backward=True, any_frame=False)
        self._frames = self.container.decode(self._stream)
        return self
