"""Volumetric tetrahedral meshes for the foam objects, from primitives or from closed surface-mesh files.

MuJoCo's flexcomp box/cylinder/ellipsoid are surface shells around one centre vertex; a foam that deforms
like foam needs a truly volumetric mesh, passed as `<flexcomp type="direct" dim="3" point=... element=...>`.
gmsh (a global singleton in the process) builds the meshes, one call at a time under a lock, silent.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import math
import signal
import sys
import threading
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from twin.interface.errors import ConfigError
from twin.sim.foam import MAX_HALF_WIDTH_M, MAX_HEIGHT_M, MIN_SIZE_M

PRIMITIVES: tuple[str, ...] = ("block", "cylinder", "sphere")
FILE_SUFFIXES: tuple[str, ...] = (".stl", ".obj")
MAX_VERTICES = 3000
"""Most mesh vertices a foam may have: each is a 3-dof body in the sim, which must stay fast."""
MIN_TETS = 4
"""Fewest tetrahedra a foam may have: fewer cannot bend or bulge at all."""
DECIMATE_ABOVE = 4
"""A surface with over this many times the decimation target is decimated; a coarser one (a CAD export, a
light scan) goes to gmsh's re-meshing as it is."""
TRIANGLES_PER_EDGE_AREA = 4.0
"""A scan is decimated to this many triangles per equilateral triangle of the foam's edge length: finer than
the tetrahedral mesh needs (gmsh re-meshes at the edge length), coarse enough to mesh in a second."""
MM_PER_FILE_UNIT_SCALE_M = 0.001
"""Default metres per file unit: scanners and CAD exports write millimetres."""
MAX_FILE_TRIANGLES = 2_000_000
"""Most triangles a surface file may have, counted before anything is welded: a 100 MB binary STL. A 10^6-
triangle scan is read, welded and checked in ~2 s and decimated in ~8-15 s (one core); a larger one is
refused in one line rather than held in memory for minutes (decimate it first with the scanner's tools)."""
MAX_MESHED_TRIANGLES = 2 * MAX_VERTICES
"""Most triangles a surface handed to gmsh as it is may have: a closed surface of T triangles has T/2 + 2
vertices, every one kept in the tetrahedral mesh, so more could only be refused after minutes of meshing
(a scan that quadric decimation cannot bring down: 1,000-triangle pole fans stall it at ~30,000)."""

_GMSH_TET = 4
"""gmsh element type of a 4-node tetrahedron."""
_GMSH_TRIANGLE = 2
"""gmsh element type of a 3-node triangle."""
_GMSH_DELAUNAY_3D = 1
_GMSH_FRONTAL_DELAUNAY_2D = 6
_FEATURE_ANGLE_RAD = math.radians(40.0)
"""Dihedral angle above which a file surface keeps a sharp edge when gmsh re-meshes it."""
_RELATIVE_AREA_TOL = 1e-12
"""A face whose area is below this fraction of the bounding-box diagonal squared counts as zero."""
_RELATIVE_VOLUME_TOL = 1e-6
"""A surface enclosing less than this fraction of its bounding-box volume counts as flat."""
_VERTICES_PER_EDGE_CUBED = 1.0
"""Fewest vertices per edge_m^3 of volume gmsh makes (measured 1.5 for the primitives, 3 for small file
surfaces): a low estimate, so the pre-check before meshing refuses only meshes sure to be too large."""

_GMSH_LOCK = threading.Lock()


@dataclass(frozen=True, eq=False)
class TetMesh:
    """A tetrahedral volume mesh in the object frame (metres, centred on the bounding-box centre, z up).

    Every tetrahedron is positively oriented and every point is used. The arrays are read-only so a cached
    mesh cannot be changed by a caller."""

    points_m: np.ndarray
    tets: np.ndarray
    surface_error_m: float = 0.0
    """How far a decimated scan's surface strays from the scan (its vertices' Hausdorff distance; 0 for a
    surface meshed as it was given)."""

    @property
    def volume_m3(self) -> float:
        """Total volume of the tetrahedra (m^3)."""
        return float(_tet_volumes_m3(self.points_m, self.tets).sum())

    @property
    def extent_m(self) -> tuple[float, float, float]:
        """Full extents of the bounding box along x, y, z (m)."""
        x, y, z = np.ptp(self.points_m, axis=0)
        return float(x), float(y), float(z)

    @property
    def boundary_faces(self) -> np.ndarray:
        """(k, 3) triangles of the tetrahedra faces that belong to one tetrahedron only, normals outward."""
        t = self.tets
        # For a positive tet (a, b, c, d) these four faces have outward normals (right-hand rule).
        faces = np.concatenate([t[:, [0, 2, 1]], t[:, [0, 1, 3]], t[:, [0, 3, 2]], t[:, [1, 2, 3]]])
        _, index, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
        return faces[np.sort(index[counts == 1])]

    @property
    def boundary_vertices(self) -> np.ndarray:
        """Sorted indices of the points on the boundary surface."""
        return np.unique(self.boundary_faces)

    @property
    def interior_vertices(self) -> np.ndarray:
        """Sorted indices of the points strictly inside the volume."""
        return np.setdiff1d(np.arange(len(self.points_m)), self.boundary_vertices)


@dataclass(frozen=True, eq=False)
class Surface:
    """A closed triangle surface read from a file, in metres (welded: shared corners are one point)."""

    points_m: np.ndarray
    triangles: np.ndarray


def _tet_volumes_m3(points_m: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volume of each tetrahedron (positive when (b-a, c-a, d-a) is right-handed)."""
    a, b, c, d = (points_m[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)) / 6.0


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.setflags(write=False)
    return array


def _mm(extent_m: tuple[float, ...] | np.ndarray) -> str:
    return " x ".join(f"{float(s) * 1e3:.1f}" for s in extent_m) + " mm"


# ---------------------------------------------------------------------------------------------- gmsh


def _restore_sigpipe(disposition: Any) -> None:
    """Put SIGPIPE back as it was: gmsh.initialize resets it to the default (terminate), under Python's
    feet, so a write to a closed socket would then kill the interpreter (exit 141) instead of raising
    BrokenPipeError. libc's signal() rather than signal.signal: it works from any thread."""
    if disposition in (signal.SIG_IGN, signal.SIG_DFL):
        ctypes.CDLL(None).signal(signal.SIGPIPE, ctypes.c_void_p(int(disposition)))
    elif threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGPIPE, disposition)


@contextlib.contextmanager
def gmsh_session() -> Iterator[Any]:
    """gmsh, initialized under the process-wide lock, silent, always finalized, with SIGPIPE restored.

    gmsh is one global state per process: every caller (the foam mesher, the FEM reference) goes through
    here. interruptible=False keeps gmsh from installing a SIGINT handler, which only the main thread may
    do; the SIGPIPE disposition gmsh resets is put back on the way out (_restore_sigpipe)."""
    import gmsh  # imported lazily: only meshing needs it

    with _GMSH_LOCK:
        sigpipe = signal.getsignal(signal.SIGPIPE)
        try:
            gmsh.initialize(readConfigFiles=False, interruptible=False)
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.option.setNumber("General.Verbosity", 0)
            yield gmsh
        finally:
            try:
                if gmsh.isInitialized():
                    gmsh.finalize()
            finally:
                _restore_sigpipe(sigpipe)


@contextlib.contextmanager
def _foam_gmsh() -> Iterator[Any]:
    """A gmsh session set up for the foam meshes: single-threaded (deterministic), fixed algorithms."""
    with gmsh_session() as gmsh:
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.option.setNumber("Mesh.MaxNumThreads1D", 1)
        gmsh.option.setNumber("Mesh.MaxNumThreads2D", 1)
        gmsh.option.setNumber("Mesh.MaxNumThreads3D", 1)
        gmsh.option.setNumber("Mesh.Algorithm", _GMSH_FRONTAL_DELAUNAY_2D)
        gmsh.option.setNumber("Mesh.Algorithm3D", _GMSH_DELAUNAY_3D)
        gmsh.model.add("foam")
        yield gmsh


def _set_uniform_size(gmsh: Any, edge_m: float) -> None:
    """Ask gmsh for edges of about edge_m everywhere (no refinement from points or curvature)."""
    opt = gmsh.option
    opt.setNumber("Mesh.MeshSizeMin", edge_m)
    opt.setNumber("Mesh.MeshSizeMax", edge_m)
    opt.setNumber("Mesh.MeshSizeFromPoints", 0)
    opt.setNumber("Mesh.MeshSizeFromCurvature", 0)
    opt.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)


def _extract_tets(gmsh: Any) -> TetMesh:
    """The generated tetrahedra as a TetMesh: unused nodes dropped, tets made positive, re-centred."""
    tags, xyz, _ = gmsh.model.mesh.getNodes()
    types, _, node_tags = gmsh.model.mesh.getElements(3)
    if _GMSH_TET not in list(types):
        return TetMesh(_frozen(np.zeros((0, 3))), _frozen(np.zeros((0, 4), dtype=np.int64)))
    tet_tags = np.asarray(node_tags[list(types).index(_GMSH_TET)], dtype=np.int64).reshape(-1, 4)
    order = np.argsort(tags)
    points = np.asarray(xyz, dtype=float).reshape(-1, 3)[order]
    tets = np.searchsorted(np.asarray(tags)[order], tet_tags)
    return _tidy(points, tets)


def _tidy(points_m: np.ndarray, tets: np.ndarray) -> TetMesh:
    """Drop unused points, renumber in first-use order, orient every tet positively, centre the box."""
    used, first = np.unique(tets.ravel(), return_index=True)
    used = used[np.argsort(first)]
    renumber = np.empty(len(points_m), dtype=np.int64)
    renumber[used] = np.arange(len(used))
    points = points_m[used]
    tets = renumber[tets]
    negative = _tet_volumes_m3(points, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    centre = (points.min(axis=0) + points.max(axis=0)) / 2.0
    return TetMesh(_frozen(points - centre), _frozen(tets))


# ------------------------------------------------------------------------------------------ primitives


def primitive_mesh(shape: str, size_m: tuple[float, float, float], edge_m: float) -> TetMesh:
    """A tetrahedral mesh of a block, elliptic cylinder or ellipsoid of full extents size_m (m).

    block: a structured (transfinite) mesh, vertices on a regular grid, flat faces and sharp corners.
    cylinder: diameters size_m[0], size_m[1], height size_m[2] along z. sphere: an ellipsoid of diameters
    size_m. Target edge length edge_m. Deterministic; cached, since scenes are rebuilt often."""
    size = tuple(float(s) for s in size_m)
    _check_primitive(shape, size, float(edge_m))
    return _primitive_mesh_cached(shape, (size[0], size[1], size[2]), float(edge_m))


def _check_primitive(shape: str, size_m: tuple[float, ...], edge_m: float) -> None:
    if shape not in PRIMITIVES:
        raise ConfigError(f"unknown mesh shape '{shape}' (choose from {', '.join(PRIMITIVES)})")
    if len(size_m) != 3 or not all(math.isfinite(s) and s > 0 for s in size_m):
        raise ConfigError(f"mesh size must be 3 positive extents in m, got {size_m}")
    _check_edge(edge_m)
    _check_edge_fits(edge_m, size_m, f"a {_mm(size_m)} {shape}")
    x, y, z = size_m
    volume_m3 = {"block": 1.0, "cylinder": math.pi / 4, "sphere": math.pi / 6}[shape] * x * y * z
    _check_estimate(volume_m3, edge_m, f"a {_mm(size_m)} {shape}")


def _check_edge(edge_m: float) -> None:
    if not (math.isfinite(edge_m) and edge_m > 0):
        raise ConfigError(f"mesh edge length must be a positive number of metres, got {edge_m:g}")


def _check_edge_fits(edge_m: float, extent_m: tuple[float, ...] | np.ndarray, what: str) -> None:
    """An edge longer than half the smallest extent leaves no room for a volume (gmsh may fail)."""
    longest_m = float(min(extent_m)) / 2
    if edge_m > longest_m * (1 + 1e-9):
        raise ConfigError(
            f"{what} cannot be meshed at {edge_m * 1e3:.1f} mm edges (at most half its smallest extent, "
            f"{longest_m * 1e3:.1f} mm): choose a shorter edge length"
        )


def _check_estimate(volume_m3: float, edge_m: float, what: str) -> None:
    """Refuse before meshing when the edge is so small that the mesh would be far too large."""
    estimate = _VERTICES_PER_EDGE_CUBED * volume_m3 / edge_m**3
    if estimate > 2 * MAX_VERTICES:
        raise ConfigError(
            f"{what} meshed at {edge_m * 1e3:.1f} mm edges needs ~{estimate:.0f} vertices "
            f"(at most {MAX_VERTICES}): choose a longer edge length"
        )


@functools.lru_cache(maxsize=64)
def _primitive_mesh_cached(shape: str, size_m: tuple[float, float, float], edge_m: float) -> TetMesh:
    with _foam_gmsh() as gmsh:
        occ = gmsh.model.occ
        x, y, z = size_m
        if shape == "block":
            occ.addBox(-x / 2, -y / 2, -z / 2, x, y, z)
            occ.synchronize()
            _make_transfinite(gmsh, edge_m)
        else:
            radius_m = x / 2
            if shape == "cylinder":
                tag = occ.addCylinder(0, 0, -z / 2, 0, 0, z, radius_m)
                occ.dilate([(3, tag)], 0, 0, 0, 1.0, y / x, 1.0)
            else:
                tag = occ.addSphere(0, 0, 0, radius_m)
                occ.dilate([(3, tag)], 0, 0, 0, 1.0, y / x, z / x)
            occ.synchronize()
            _set_uniform_size(gmsh, edge_m)
        gmsh.model.mesh.generate(3)
        mesh = _extract_tets(gmsh)
    _check_counts(mesh, edge_m, f"a {_mm(size_m)} {shape}")
    return mesh


def _make_transfinite(gmsh: Any, edge_m: float) -> None:
    """Structured grid on an axis-aligned box: round(length / edge) cells along every edge."""
    model = gmsh.model
    for _, curve in model.getEntities(1):
        x0, y0, z0, x1, y1, z1 = model.getBoundingBox(1, curve)
        length_m = max(x1 - x0, y1 - y0, z1 - z0)
        model.mesh.setTransfiniteCurve(curve, max(1, round(length_m / edge_m)) + 1)
    for _, surface in model.getEntities(2):
        model.mesh.setTransfiniteSurface(surface)
    for _, volume in model.getEntities(3):
        model.mesh.setTransfiniteVolume(volume)


def _check_counts(mesh: TetMesh, edge_m: float, what: str) -> None:
    n_points, n_tets = len(mesh.points_m), len(mesh.tets)
    if n_points > MAX_VERTICES:
        raise ConfigError(
            f"{what} meshed at {edge_m * 1e3:.1f} mm edges has {n_points} vertices "
            f"(at most {MAX_VERTICES}): choose a longer edge length"
        )
    if n_tets < MIN_TETS:
        raise ConfigError(
            f"{what} meshed at {edge_m * 1e3:.1f} mm edges has only {n_tets} tetrahedra "
            f"(at least {MIN_TETS}): choose a shorter edge length"
        )
    if _tet_volumes_m3(mesh.points_m, mesh.tets).min() <= _RELATIVE_VOLUME_TOL * edge_m**3:
        raise ConfigError(f"{what} meshed at {edge_m * 1e3:.1f} mm edges has flat tetrahedra (degenerate)")
    pieces = _count_pieces(mesh)
    if pieces > 1:
        raise ConfigError(f"{what} is {pieces} separate pieces, not one foam object")


def _count_pieces(mesh: TetMesh) -> int:
    """Number of connected groups of tetrahedra (joined through shared vertices)."""
    return _count_surface_pieces(len(mesh.points_m), mesh.tets)


def _count_surface_pieces(n_points: int, cells: np.ndarray) -> int:
    """Number of connected groups of cells (triangles or tetrahedra) joined through shared vertices."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = np.repeat(cells[:, 0], cells.shape[1] - 1)
    cols = cells[:, 1:].ravel()
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_points, n_points))
    return int(connected_components(graph, directed=False)[0])


# ---------------------------------------------------------------------------------------- mesh files


def load_surface(path: Path, scale: float = MM_PER_FILE_UNIT_SCALE_M) -> Surface:
    """Read a closed triangle surface from .stl (ascii or binary) or .obj; scale = metres per file unit.

    The default scale 0.001 reads the file as millimetres, as scanners and CAD exports write. Shared
    corners are welded and an inside-out surface turned over; ConfigError (one line) for a missing,
    empty, unparsable, too large, open, inconsistently oriented or degenerate file. Cached on the file's
    path, size and modification time, so the scene, the mesher and the calibration read a file once."""
    path = Path(path)
    where = f"mesh file '{path}'"
    if not (math.isfinite(scale) and scale > 0):
        raise ConfigError(f"{where}: scale must be a positive number of metres per file unit, got {scale:g}")
    try:
        stat = path.stat()
        key = (stat.st_size, stat.st_mtime_ns)
    except OSError:
        key = (-1, -1)  # _read_triangles says what is wrong
    return _load_surface_cached(str(path), key, float(scale))


@functools.lru_cache(maxsize=2)
def _load_surface_cached(path_name: str, key: tuple[int, int], scale: float) -> Surface:
    path = Path(path_name)
    where = f"mesh file '{path}'"
    points, triangles = _read_triangles(path, where)
    points_m, triangles = _weld(points * scale, triangles)
    _check_not_degenerate(points_m, triangles, where)  # first: welding a flat surface makes it non-manifold
    _check_closed(triangles, where)
    pieces = _count_surface_pieces(len(points_m), triangles)
    if pieces > 1:
        raise ConfigError(f"{where}: the surface is {pieces} separate pieces (one closed surface per file)")
    return Surface(_frozen(points_m), _frozen(_outward(triangles, points_m)))


_STL_RECORD = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
"""One facet of a binary STL (50 bytes)."""
_STL_HEADER_BYTES = 84
"""A binary STL's 80-byte header and its uint32 facet count."""


def _check_triangle_budget(count: int, where: str) -> None:
    if count > MAX_FILE_TRIANGLES:
        raise ConfigError(
            f"{where}: {count:,} triangles, more than the {MAX_FILE_TRIANGLES:,} a foam is made from "
            "(decimate the scan first, e.g. to 100,000 triangles)"
        )


def _binary_stl_count(path: Path) -> int | None:
    """The facet count of a binary STL, None for any other file: its size must be 84 + 50 x its count."""
    size = path.stat().st_size
    if size < _STL_HEADER_BYTES:
        return None
    with path.open("rb") as f:
        f.seek(80)
        count = int(np.frombuffer(f.read(4), dtype="<u4")[0])
    return count if size == _STL_HEADER_BYTES + _STL_RECORD.itemsize * count else None


def _read_triangles(path: Path, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Points and triangles (quads and polygons fanned), a binary STL read directly (its facet count
    checked against MAX_FILE_TRIANGLES before a byte of it is read), any other file as meshio reads it;
    ConfigError when it cannot."""
    suffix = path.suffix.lower()
    if suffix not in FILE_SUFFIXES:
        raise ConfigError(f"{where}: unsupported format '{suffix}' (use {' or '.join(FILE_SUFFIXES)})")
    if not path.is_file():
        raise ConfigError(f"{where}: no such file")
    try:
        if path.stat().st_size == 0:
            raise ConfigError(f"{where}: the file is empty")
        count = _binary_stl_count(path) if suffix == ".stl" else None
        if count is not None:
            _check_triangle_budget(count, where)
            corners = np.fromfile(path, dtype=_STL_RECORD, offset=_STL_HEADER_BYTES)["corners"]
            points = corners.reshape(-1, 3).astype(float) + 0.0  # + 0.0: -0.0 and 0.0 are one point
            triangles = np.arange(len(points), dtype=np.int64).reshape(-1, 3)
        else:
            points, triangles = _read_with_meshio(path, suffix, where)
    except ConfigError:
        raise
    except OSError as exc:
        raise ConfigError(f"{where}: cannot be read ({exc.strerror or exc})") from None
    if len(points) == 0 or len(triangles) == 0:
        raise ConfigError(f"{where}: no triangles found (empty, or not a surface mesh)")
    if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
        raise ConfigError(f"{where}: vertices must be finite 3D points")
    if triangles.min() < 0 or triangles.max() >= len(points):
        raise ConfigError(f"{where}: faces refer to vertices that do not exist")
    return points, triangles


def _read_with_meshio(path: Path, suffix: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    import meshio  # imported lazily: only mesh files need it

    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            mesh = meshio.read(path, file_format=suffix[1:])
    except OSError:
        raise
    except Exception:
        raise ConfigError(f"{where}: cannot be parsed as {suffix[1:].upper()}") from None
    points = np.asarray(mesh.points, dtype=float)
    faces = [_fan(np.asarray(block.data, dtype=np.int64)) for block in mesh.cells if block.type != "vertex"]
    faces = [f for f in faces if len(f)]
    if not faces:
        raise ConfigError(f"{where}: no triangles found (empty, or not a surface mesh)")
    triangles = np.concatenate(faces)
    _check_triangle_budget(len(triangles), where)  # before welding: an ASCII file is counted once parsed
    return points, triangles


def _fan(faces: np.ndarray) -> np.ndarray:
    """Triangles of polygon faces (k, n >= 3) by fanning from the first corner; lines and points dropped."""
    if faces.ndim != 2 or faces.shape[1] < 3:
        return np.zeros((0, 3), dtype=np.int64)
    return np.concatenate([faces[:, [0, i, i + 1]] for i in range(1, faces.shape[1] - 1)])


def _weld(points_m: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge equal points (STL repeats every corner) and drop points no face uses: one lexicographic
    sort of the points (np.unique(axis=0) takes ~6x longer on a 10^6-triangle STL's 3 x 10^6 corners)."""
    points_m = np.asarray(points_m, dtype=float)
    order = np.lexsort(points_m.T[::-1])
    ordered = points_m[order]
    first = np.ones(len(ordered), dtype=bool)
    first[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
    inverse = np.empty(len(points_m), dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    unique = ordered[first]
    triangles = inverse[np.asarray(triangles, dtype=np.int64)]
    used = np.zeros(len(unique), dtype=bool)
    used[triangles.ravel()] = True
    if used.all():
        return unique, triangles
    renumber = np.cumsum(used) - 1
    return unique[used], renumber[triangles]


def _edge_keys(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle's three edges as int64 keys: directed (from * n + to) and undirected (low * n +
    high), n the number of points; sorting these is fast where np.unique(axis=0) on pairs is not."""
    n = int(triangles.max()) + 1
    start = triangles.ravel().astype(np.int64)
    end = triangles[:, [1, 2, 0]].ravel().astype(np.int64)
    return start * n + end, np.minimum(start, end) * n + np.maximum(start, end)


def _run_lengths(keys: np.ndarray) -> np.ndarray:
    """How often each distinct key occurs."""
    ordered = np.sort(keys)
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    return np.diff(np.r_[starts, len(ordered)])


def _check_closed(triangles: np.ndarray, where: str) -> None:
    """A volume needs a watertight, manifold, consistently oriented surface: every edge shared by exactly
    two faces, which run along it in opposite directions."""
    directed, undirected = _edge_keys(triangles)
    counts = _run_lengths(undirected)
    open_edges = int((counts == 1).sum())
    non_manifold = int((counts > 2).sum())
    if open_edges or non_manifold:
        parts = []
        if open_edges:
            parts.append(f"{open_edges} open edge{'s' if open_edges != 1 else ''} (holes)")
        if non_manifold:
            parts.append(f"{non_manifold} non-manifold edge{'s' if non_manifold != 1 else ''} (>2 faces)")
        raise ConfigError(f"{where}: the surface is not watertight: {' and '.join(parts)}")
    same_way = int((_run_lengths(directed) > 1).sum())
    if same_way:
        edges = f"{same_way} edge{'s' if same_way != 1 else ''}"
        raise ConfigError(
            f"{where}: the faces are not consistently oriented ({edges} run the same way in both of their "
            "faces: some normals point in, some out)"
        )


def _signed_volume_m3(points_m: np.ndarray, triangles: np.ndarray) -> float:
    """The volume a closed surface encloses (divergence theorem): positive when its normals point out."""
    a, b, c = (points_m[triangles[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->", a, np.cross(b, c))) / 6.0


def _outward(triangles: np.ndarray, points_m: np.ndarray) -> np.ndarray:
    """The triangles of a closed, consistently oriented surface with their normals pointing out: one
    whose normals all point in (a CAD export wound the other way) encloses a negative volume, and is
    turned over (unambiguous once the orientation is consistent)."""
    if _signed_volume_m3(points_m, triangles) < 0:
        return triangles[:, [0, 2, 1]]
    return triangles


def _check_not_degenerate(points_m: np.ndarray, triangles: np.ndarray, where: str) -> None:
    """Refuse zero-area faces and a surface that encloses no volume (flat)."""
    a, b, c = (points_m[triangles[:, i]] for i in range(3))
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    diagonal_m = float(np.linalg.norm(np.ptp(points_m, axis=0)))
    zero = int((area2 <= _RELATIVE_AREA_TOL * diagonal_m**2).sum())
    extent = np.ptp(points_m, axis=0)
    enclosed_m3 = abs(float(np.einsum("ij,ij->", a, np.cross(b, c)))) / 6.0
    if enclosed_m3 <= _RELATIVE_VOLUME_TOL * float(np.prod(extent)) or zero == len(triangles):
        raise ConfigError(f"{where}: the surface encloses no volume (flat or degenerate, {_mm(extent)})")
    if zero:
        raise ConfigError(f"{where}: {zero} of {len(triangles)} faces have zero area (degenerate surface)")


def _check_fits(extent_m: np.ndarray, where: str) -> None:
    x, y, z = (float(e) for e in extent_m)
    if max(x, y) / 2 > MAX_HALF_WIDTH_M or z > MAX_HEIGHT_M:
        raise ConfigError(
            f"{where}: {_mm(extent_m)} does not fit in the hand (footprint <= "
            f"{2 * MAX_HALF_WIDTH_M * 1e3:.0f} mm, height <= {MAX_HEIGHT_M * 1e3:.0f} mm; "
            "is the scale right?)"
        )
    if min(x, y, z) < MIN_SIZE_M:
        raise ConfigError(
            f"{where}: {_mm(extent_m)} is too small (every extent >= {MIN_SIZE_M * 1e3:.0f} mm; "
            "is the scale right?)"
        )


def file_mesh(path: Path, edge_m: float, scale: float = MM_PER_FILE_UNIT_SCALE_M) -> TetMesh:
    """Tetrahedralise the closed surface in an .stl/.obj file at target edge length edge_m (m).

    scale is metres per file unit (default 0.001: the file is in millimetres). The surface is re-meshed
    at edge_m, re-centred on its bounding-box centre and keeps its orientation (z up as in the file).
    Cached on the file's path, size and modification time."""
    path = Path(path)
    _check_edge(float(edge_m))
    try:
        stat = path.stat()
        key = (stat.st_size, stat.st_mtime_ns)
    except OSError:
        key = (-1, -1)  # load_surface says what is wrong
    return _file_mesh_cached(str(path), key, float(edge_m), float(scale))


@functools.lru_cache(maxsize=16)
def _file_mesh_cached(path: str, key: tuple[int, int], edge_m: float, scale: float) -> TetMesh:
    from twin.processes import run_killable

    where = f"mesh file '{path}'"
    surface = load_surface(Path(path), scale)
    extent_m = np.ptp(surface.points_m, axis=0)
    _check_fits(extent_m, where)
    _check_edge_fits(edge_m, extent_m, where)
    _check_estimate(_signed_volume_m3(surface.points_m, surface.triangles), edge_m, where)
    target = _decimation_target(surface, edge_m)
    said = None
    if target is not None:  # said once the worker exists: from then on a Ctrl-C ends it
        line = f"{where}: {len(surface.triangles):,} triangles, decimating to ~{target:,} for the foam's "
        said = functools.partial(_say, f"{line}{edge_m * 1e3:.1f} mm mesh...")
    # gmsh and the decimation are C code that a Ctrl-C cannot stop: they run in a process killed on one
    return run_killable(_mesh_surface, surface, edge_m, where, started=said)


def _say(message: str) -> None:
    print(f"twin: {message}", file=sys.stderr, flush=True)


def _mesh_surface(surface: Surface, edge_m: float, where: str) -> TetMesh:
    """The foam's tetrahedra for a loaded surface: decimated if it is a dense scan, checked for crossing
    itself, filled by gmsh, checked against the surface's own volume (run_killable runs this)."""
    decimated, error_m = _decimate(surface, edge_m, where)
    if decimated is not surface and len(decimated.triangles) > MAX_MESHED_TRIANGLES:
        raise ConfigError(
            f"{where}: its {len(surface.triangles):,} triangles could be decimated only to "
            f"{len(decimated.triangles):,} (at most {MAX_MESHED_TRIANGLES:,} are meshed as they are; fans of "
            "very thin triangles stall the decimation): re-mesh the scan more evenly first"
        )
    try:
        _check_self_intersections(decimated, where)
    except ConfigError as exc:
        if decimated is surface:
            raise
        raise ConfigError(  # the scan may be sound: quadric decimation can fold a surface onto itself
            f"{exc} after decimating the scan to {len(decimated.triangles)} triangles (re-mesh it more "
            "evenly first)"
        ) from None
    mesh = _tetrahedralise(decimated, edge_m, where, remesh=decimated is surface)
    _check_counts(mesh, edge_m, where)
    _check_volume(mesh, decimated, where, remeshed=decimated is surface)
    return TetMesh(mesh.points_m, mesh.tets, surface_error_m=error_m)


def _decimation_target(surface: Surface, edge_m: float) -> int | None:
    """How many triangles a scan finer than the foam's edge length is decimated to: about
    TRIANGLES_PER_EDGE_AREA per equilateral triangle of edge_m over its area; None for a surface within
    DECIMATE_ABOVE times that, which gmsh re-meshes at edge_m as it is."""
    a, b, c = (surface.points_m[surface.triangles[:, i]] for i in range(3))
    area_m2 = float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()) / 2.0
    target = max(64, round(TRIANGLES_PER_EDGE_AREA * area_m2 / (math.sqrt(3.0) / 4.0 * edge_m**2)))
    return None if len(surface.triangles) <= DECIMATE_ABOVE * target else target


def decimated_surface(surface: Surface, edge_m: float, where: str) -> Surface:
    """`surface` decimated for edge_m (_decimate) in a worker a Ctrl-C kills at once (the quadric
    decimation of a 10^6-triangle scan is ~8 s of C code); `surface` itself if it needs none."""
    if _decimation_target(surface, edge_m) is None:
        return surface
    from twin.processes import run_killable

    return run_killable(_decimate, surface, edge_m, where)[0]


def _decimate(surface: Surface, edge_m: float, where: str) -> tuple[Surface, float]:
    """A scan finer than the foam's edge length, decimated (fast-simplification's quadric decimation) to
    _decimation_target's count, and how far it moved (the Hausdorff distance, sampled); a coarser one is
    kept as it is (error 0)."""
    target = _decimation_target(surface, edge_m)
    if target is None:
        return surface, 0.0
    import fast_simplification
    from scipy.spatial import cKDTree

    points, triangles = fast_simplification.simplify(
        np.array(surface.points_m, dtype=np.float64, order="C"),
        np.array(surface.triangles, dtype=np.int64, order="C"),
        target_reduction=1.0 - target / len(surface.triangles),
    )
    points_m, triangles = _weld(np.asarray(points, float), np.asarray(triangles, np.int64))
    try:
        _check_not_degenerate(points_m, triangles, where)
        _check_closed(triangles, where)
    except ConfigError as exc:
        raise ConfigError(f"{exc} after decimating the scan to {len(triangles)} triangles") from None
    # Hausdorff distance, each surface sampled: the scan by its vertices, the decimated one also inside
    # its triangles (a 4 x 4 barycentric grid), so a vertex's distance is to the surface, not to a vertex
    w = np.array([(i, j, 4 - i - j) for i in range(5) for j in range(5 - i)], float) / 4.0
    samples = np.einsum("sk,tkd->tsd", w, points_m[triangles]).reshape(-1, 3)
    error_m = max(
        float(cKDTree(samples).query(surface.points_m)[0].max()),
        float(cKDTree(surface.points_m).query(points_m)[0].max()),
    )
    return Surface(_frozen(points_m), _frozen(triangles)), error_m


_ORIENT_TOL = 1e-12
"""An orientation (six times a tetrahedron's signed volume) below this fraction of the bounding-box
diagonal cubed counts as zero: an edge ending on a plane, or lying in it, does not cross it."""


_PAIRS_PER_CHUNK = 200_000
"""Candidate triangle pairs tested at a time (~100 MB of arrays): memory stays bounded on any surface."""


def _check_self_intersections(surface: Surface, where: str) -> None:
    """Refuse a surface that crosses itself (a fold pushed through the far side, two overlapping shells
    joined at a corner): it bounds no single volume, and gmsh may mesh it into another one.

    Two triangles that share no corner cross when an edge of one passes through the other (its interior
    or its boundary); in a surface that bounds a volume such triangles have no point in common. Candidate
    pairs are those whose bounding boxes overlap (a sweep along x, then y and z), tested vectorised in
    chunks: ~0.1 s for 10^4 triangles. Not detected: triangles overlapping within one plane, and two
    triangles that share a corner crossing (a surface folded through a single vertex)."""
    points, triangles = surface.points_m, surface.triangles
    corners = points[triangles]
    low, high = corners.min(axis=1), corners.max(axis=1)
    tol = _ORIENT_TOL * float(np.linalg.norm(np.ptp(points, axis=0))) ** 3
    order = np.argsort(low[:, 0], kind="stable")
    sorted_low_x = low[order, 0]
    # triangle order[r] meets (in x) order[r + 1 : end[r]]: those starting before it ends
    end = np.searchsorted(sorted_low_x, high[order, 0], side="right")
    counts = np.maximum(end - np.arange(len(order)) - 1, 0)
    count = 0
    rows = np.arange(len(order))
    for chunk in np.array_split(rows, max(1, int(counts.sum()) // _PAIRS_PER_CHUNK + 1)):
        n = counts[chunk]
        first = np.repeat(chunk, n)
        offset = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        i, j = order[first], order[first + 1 + offset]
        meet = np.all((low[i, 1:] <= high[j, 1:]) & (low[j, 1:] <= high[i, 1:]), axis=1)
        i, j = i[meet], j[meet]
        share = (triangles[i][:, :, None] == triangles[j][:, None, :]).any(axis=(1, 2))
        i, j = i[~share], j[~share]
        crossing = _edges_cross(corners[i], corners[j], tol) | _edges_cross(corners[j], corners[i], tol)
        count += int(crossing.sum())
    if count:
        raise ConfigError(
            f"{where}: the surface is self-intersecting ({count} pair{'s' if count != 1 else ''} of its "
            "triangles cross): it bounds no single volume"
        )


def _orient(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Six times the signed volume of tetrahedra (a, b, c, d), row by row."""
    return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a))


def _edges_cross(edges_of: np.ndarray, triangles: np.ndarray, tol: float) -> np.ndarray:
    """For (k, 3, 3) triangle pairs: does any edge of edges_of[n] pass through triangles[n] (its interior
    or its edges: a symmetric surface's crossings all fall on edges)? The edge must cross the plane
    strictly, so an edge lying in it (coplanar triangles) does not count."""
    t0, t1, t2 = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    hit = np.zeros(len(triangles), dtype=bool)
    for u, v in ((0, 1), (1, 2), (2, 0)):
        p, q = edges_of[:, u], edges_of[:, v]
        sp, sq = _orient(t0, t1, t2, p), _orient(t0, t1, t2, q)
        through_plane = ((sp > tol) & (sq < -tol)) | ((sp < -tol) & (sq > tol))
        w0, w1, w2 = _orient(p, q, t0, t1), _orient(p, q, t1, t2), _orient(p, q, t2, t0)
        inside = ((w0 >= -tol) & (w1 >= -tol) & (w2 >= -tol)) | ((w0 <= tol) & (w1 <= tol) & (w2 <= tol))
        hit |= through_plane & inside
    return hit


VOLUME_TOLERANCE_REMESHED = 0.20
"""How far the tetrahedra's volume may stray from the volume a surface gmsh re-meshes at the foam's edge
length encloses (its signed volume, by the divergence theorem), as a fraction: the re-meshed surface cuts
chords across a curved one. Measured on well-formed surfaces at
10, 15 mm and each one's default edge: a 12-triangle block 0.00 %, a 384-triangle cylinder -1.0 to -2.4 %,
notebook 05's egg and a bumpy egg (2,112 triangles) -3.2 to -7.5 %, a 1,280-triangle scanner-like egg
-5.1 to -10.8 % (at 15 mm; -8.6 % at its default 12.9 mm). 0.20 leaves ~2x that margin."""
VOLUME_TOLERANCE_AS_GIVEN = 0.01
"""The same for a surface meshed as it is (a decimated scan: gmsh keeps its triangles as the boundary):
measured within 0.01 % on the library sphere and scanner-like eggs of 5,120 to 81,920 triangles decimated
for 10 to 15 mm edges; 1 % is far outside rounding and far inside any fold or lost region."""


def _check_volume(mesh: TetMesh, surface: Surface, where: str, remeshed: bool) -> None:
    """Refuse tetrahedra that do not fill the surface's own volume (gmsh filling another region)."""
    enclosed_m3 = _signed_volume_m3(surface.points_m, surface.triangles)
    error = mesh.volume_m3 / enclosed_m3 - 1.0
    tolerance = VOLUME_TOLERANCE_REMESHED if remeshed else VOLUME_TOLERANCE_AS_GIVEN
    if not abs(error) <= tolerance:
        raise ConfigError(
            f"{where}: the tetrahedra fill {mesh.volume_m3 * 1e6:.2f} cm^3 but the surface encloses "
            f"{enclosed_m3 * 1e6:.2f} cm^3 ({100 * error:+.1f} %, at most +-{100 * tolerance:.0f} %): "
            "a self-intersecting surface, or one gmsh could not follow"
        )


def _tetrahedralise(surface: Surface, edge_m: float, where: str, remesh: bool = True) -> TetMesh:
    """Re-mesh the surface at edge_m with gmsh (classify, re-parametrise) and fill it with tetrahedra; a
    surface already at the foam's density (a decimated scan: `remesh` False) is filled as it is."""
    with _foam_gmsh() as gmsh:
        model = gmsh.model
        centre = (surface.points_m.min(axis=0) + surface.points_m.max(axis=0)) / 2.0
        entity = model.addDiscreteEntity(2)
        node_tags = np.arange(1, len(surface.points_m) + 1)
        model.mesh.addNodes(2, entity, node_tags, (surface.points_m - centre).ravel())
        model.mesh.addElementsByType(entity, _GMSH_TRIANGLE, [], (surface.triangles + 1).ravel())
        try:
            if remesh:
                model.mesh.classifySurfaces(_FEATURE_ANGLE_RAD, True, True, math.pi)
                model.mesh.createGeometry()
            surfaces = [tag for _, tag in model.getEntities(2)]
            loop = model.geo.addSurfaceLoop(surfaces)
            model.geo.addVolume([loop])
            model.geo.synchronize()
            _set_uniform_size(gmsh, edge_m)
            gmsh.option.setNumber("Mesh.OptimizeNetgen", 0 if remesh else 1)  # slivers at a decimated surface
            model.mesh.generate(3)
        except Exception as exc:
            detail = " ".join(str(exc).split()) or type(exc).__name__
            raise ConfigError(
                f"{where}: gmsh could not fill the surface with tetrahedra (self-intersecting surface, or an "
                f"edge length too coarse for its detail?): {detail}"
            ) from None
        mesh = _extract_tets(gmsh)
    if len(mesh.tets) == 0:
        raise ConfigError(f"{where}: gmsh made no tetrahedra (self-intersecting or badly shaped surface?)")
    return mesh
