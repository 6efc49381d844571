"""torchvision 0.25.0's `transforms.ToTensor` for PIL images and numpy arrays (torchvision/transforms/
functional.py: to_tensor), without accimage and its API-usage logging; the stand-in's docstring says why."""

import sys

import numpy as np
import torch
from PIL import Image


class ToTensor:
    """A PIL image or an HWC ndarray as a CHW tensor: uint8 scaled to float in [0, 1], others as they are."""

    def __call__(self, pic: Image.Image | np.ndarray) -> torch.Tensor:
        default_float_dtype = torch.get_default_dtype()
        if isinstance(pic, np.ndarray):
            if pic.ndim not in (2, 3):
                raise ValueError(f"pic should be 2/3 dimensional. Got {pic.ndim} dimensions.")
            if pic.ndim == 2:
                pic = pic[:, :, None]
            img = torch.from_numpy(pic.transpose((2, 0, 1))).contiguous()
            return img.to(dtype=default_float_dtype).div(255) if img.dtype == torch.uint8 else img
        if not isinstance(pic, Image.Image):
            raise TypeError(f"pic should be PIL Image or ndarray. Got {type(pic)}")
        i16 = "I;16" if sys.byteorder == "little" else "I;16B"
        mode_to_nptype = {"I": np.int32, i16: np.int16, "F": np.float32}
        img = torch.from_numpy(np.array(pic, mode_to_nptype.get(pic.mode, np.uint8), copy=True))
        if pic.mode == "1":
            img = 255 * img
        img = img.view(pic.size[1], pic.size[0], len(pic.getbands()))
        img = img.permute((2, 0, 1)).contiguous()  # HWC -> CHW
        return img.to(dtype=default_float_dtype).div(255) if img.dtype == torch.uint8 else img

    def __repr__(self) -> str:
        return f"{self.__class__.__name__}()"
