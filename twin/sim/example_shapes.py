"""Closed surfaces to try the foam library on, written as STL as a scanner would leave them: an
egg-shaped or bumpy ellipsoid in millimetres (tests, benchmarks and notebook 05 use them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_closed_surface(
    path: Path,
    radii_mm: tuple[float, float, float],
    *,
    egg: float = 0.0,
    bump: float = 0.0,
    rings: int = 20,
    segments: int = 40,
) -> Path:
    """A closed UV ellipsoid with semi-axes `radii_mm`, `egg` wider towards +z (fraction) and `bump`
    ripples (fraction of the radius), as binary STL at `path`."""
    import meshio

    theta = np.linspace(0, np.pi, rings)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    r = 1 + bump * np.sin(3 * t) * np.cos(4 * p)
    waist = r * (1 + egg * np.cos(t))
    rx, ry, rz = radii_mm
    ring = np.c_[(rx * waist * np.sin(t) * np.cos(p)).ravel(), (ry * waist * np.sin(t) * np.sin(p)).ravel()]
    points = np.vstack([np.c_[ring, (rz * r * np.cos(t)).ravel()], [0, 0, rz], [0, 0, -rz]])
    top, bottom = len(points) - 2, len(points) - 1

    def at(i: int, j: int) -> int:
        return i * segments + j % segments

    triangles = []
    for i in range(len(theta) - 1):
        for j in range(segments):
            triangles += [
                [at(i, j), at(i + 1, j), at(i, j + 1)],
                [at(i, j + 1), at(i + 1, j), at(i + 1, j + 1)],
            ]
    last = len(theta) - 1
    for j in range(segments):
        triangles += [[top, at(0, j), at(0, j + 1)], [bottom, at(last, j + 1), at(last, j)]]
    meshio.write(path, meshio.Mesh(points, [("triangle", np.array(triangles))]), binary=True)
    return path
