"""torchvision 0.25.0's `io.VideoReader` on its "pyav" backend (torchvision/io/video_reader.py), the only
backend it can have here; the stand-in's docstring says why. Frames as torchvision gives them: RGB uint8
CHW tensors, `pts` in seconds."""

from collections.abc import Iterator
from typing import Any

import av
import torch

av.logging.set_level(av.logging.ERROR)


class VideoReader:
    """One stream of a video file, frame by frame (`next`), from a seek point (`seek`)."""

    def __init__(self, src: str, stream: str = "video", num_threads: int = 0) -> None:
        if not isinstance(src, str) or not src:
            raise ValueError(f"the torchvision stand-in reads video files by path, not {src!r}")
        self.container = av.open(src, metadata_errors="ignore")
        stream_type = stream.split(":")[0]
        stream_id = 0 if len(stream.split(":")) == 1 else int(stream.split(":")[1])
        self.pyav_stream = {stream_type: stream_id}
        self._c = self.container.decode(**self.pyav_stream)

    def __next__(self) -> dict[str, Any]:
        try:
            frame = next(self._c)
            pts = float(frame.pts * frame.time_base)
            if "video" in self.pyav_stream:
                frame = torch.as_tensor(frame.to_rgb().to_ndarray()).permute(2, 0, 1)
            elif "audio" in self.pyav_stream:
                frame = torch.as_tensor(frame.to_ndarray()).permute(1, 0)
            else:
                frame = None
        except av.error.EOFError:
            raise StopIteration from None
        if frame.numel() == 0:
            raise StopIteration
        return {"data": frame, "pts": pts}

    def __iter__(self) -> Iterator[dict[str, Any]]:
        return self

    def seek(self, time_s: float, keyframes_only: bool = False) -> "VideoReader":
        """To the key frame at or before `time_s` (PyAV seeks no closer: torchvision warns where
        `keyframes_only` is False; LeRobot always passes True on this backend)."""
        temp_str = self.container.streams.get(**self.pyav_stream)[0]
        offset = round(max(time_s, 0) / temp_str.time_base)
        self.container.seek(offset, backward=True, any_frame=False, stream=temp_str)
        self._c = self.container.decode(**self.pyav_stream)
        return self
