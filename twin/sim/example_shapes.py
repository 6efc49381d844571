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


def write_scan_like_surface(
    path: Path, radii_mm: tuple[float, float, float], *, egg: float = 0.0, subdivisions: int = 3
) -> Path:
    """The egg of write_closed_surface as a scanner's uniform triangulation (a subdivided icosahedron:
    20 * 4**subdivisions triangles of near-equal size, no pole fans), as binary STL at `path`."""
    import meshio

    t = (1 + 5**0.5) / 2
    points = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float
    )  # fmt: skip
    faces = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
         [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    )  # fmt: skip
    for _ in range(subdivisions):  # split every triangle in four at its edges' midpoints
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = len(points) + inverse.reshape(3, -1).T
        points = np.vstack([points, points[unique].mean(axis=1)])
        a, b, c = faces.T
        ab, bc, ca = mid.T
        faces = np.concatenate([np.c_[a, ab, ca], np.c_[ab, b, bc], np.c_[ca, bc, c], np.c_[ab, bc, ca]])
    unit = points / np.linalg.norm(points, axis=1, keepdims=True)
    waist = 1 + egg * unit[:, 2]
    scaled = unit * np.array(radii_mm) * np.c_[waist, waist, np.ones(len(unit))]
    meshio.write(path, meshio.Mesh(scaled, [("triangle", faces)]), binary=True)
    return path
