"""Empty: lerobot 0.4.4's processor package imports `torchvision.transforms.functional` at module level
(for the crops and resizes of its human-in-the-loop processor), and importing any policy config, ACT's
included, imports that package. Nothing the side environment runs calls it; a call fails here."""
