"""`transforms.ToTensor`, the one transform LeRobot's dataset loader applies (to the PIL images it reads
from parquet), written to torchvision's documented behaviour, not from its code; the stand-in's docstring
says why. 8-bit images only: anything else fails loudly rather than converting differently."""

import numpy as np
import torch
from PIL import Image


class ToTensor:
    """An 8-bit PIL image or HxW(xC) uint8 array as a CxHxW float tensor in [0, 1], as torchvision's does."""

    def __call__(self, pic: Image.Image | np.ndarray) -> torch.Tensor:
        if not isinstance(pic, Image.Image | np.ndarray):
            raise TypeError(f"the torchvision stand-in converts PIL images and arrays, not {type(pic)}")
        array = np.asarray(pic)
        if array.dtype != np.uint8 or array.ndim not in (2, 3):
            raise ValueError(
                f"the torchvision stand-in converts 8-bit images only, not {array.dtype} {array.shape}"
            )
        channels_first = np.ascontiguousarray(np.atleast_3d(array).transpose(2, 0, 1))
        return torch.from_numpy(channels_first).to(torch.get_default_dtype()).div(255)

    def __repr__(self) -> str:
        return "ToTensor()"
