"""Empty (see the package's docstring): imported by lerobot's datasets/transforms.py, called by none of
what the side environment runs."""
