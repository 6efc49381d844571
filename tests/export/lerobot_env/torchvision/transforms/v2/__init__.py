"""Import-time names only: lerobot 0.4.4's datasets/transforms.py (which every policy config imports, through
lerobot.configs.default) subclasses `torchvision.transforms.v2.Transform` for its optional training-time
image augmentations. The side environment loads datasets without them; making one fails here."""

import torch

from . import functional


class Transform(torch.nn.Module):
    """A base class that cannot be instantiated: the stand-in has no image augmentations."""

    def __init__(self) -> None:
        raise NotImplementedError("the torchvision stand-in (tests/export/lerobot_env) has no transforms")


__all__ = ["Transform", "functional"]
