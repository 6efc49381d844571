"""The faithful foam is a volumetric mesh that dents locally and bulges; mesh foams run end to end."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from benchmarks.foam_fidelity import simulate
from twin.cli import main
from twin.interface.errors import ConfigError
from twin.recording.reader import open_run
from twin.sim.example_shapes import write_closed_surface
from twin.sim.foam import LIBRARY, mesh_object
from twin.sim.scene import build_model, foam_mesh


def _bumpy_sphere_stl(path: Path, radius_mm: float = 30.0, bump: float = 0.08) -> Path:
    """A closed bumpy sphere (millimetres), written as binary STL."""
    return write_closed_surface(path, (radius_mm,) * 3, bump=bump)


def test_the_faithful_foam_is_a_volumetric_mesh_with_interior_vertices():
    for name, foam in LIBRARY.items():
        faithful = foam.with_overrides(fidelity="faithful")
        mesh = foam_mesh(faithful)
        assert len(mesh.interior_vertices) > 0, name  # not a surface shell around one centre vertex
        model = build_model(faithful)
        assert model.nflexvert == len(mesh.points_m)
        assert model.flex_dim[0] == 3 and model.nflexelem == len(mesh.tets)
        assert model.flex_interp[0] == 0  # full dof: every vertex moves on its own


def test_a_fingertip_leaves_a_local_dent_where_the_fast_foam_moves_its_whole_face():
    """The 23 x 50 mm punch at 6 mm: the faithful block's face under the punch sinks millimetres below its
    corners; the trilinear face stays planar (its nodes are the corners), so it cannot."""

    def dent_and_bulge_mm(fidelity: str) -> tuple[float, float]:
        sim = simulate(LIBRARY["block"].with_overrides(fidelity=fidelity), "punch")
        rest, moved = sim["rest"], sim["shape_6mm"]
        face = rest[:, 1] < rest[:, 1].min() + 1e-4
        dy = (moved[face, 1] - rest[face, 1]) * 1e3
        xz = rest[face][:, [0, 2]] - [0.0, rest[:, 2].mean()]
        under = (np.abs(xz[:, 0]) <= 0.0115) & (np.abs(xz[:, 1]) <= 0.025)
        corners = (np.abs(xz[:, 0]) > 0.025) & (np.abs(xz[:, 1]) > 0.03)
        top = rest[:, 2] > rest[:, 2].max() - 1e-4
        bulge_mm = float((moved[top, 2] - rest[top, 2]).max() * 1e3)
        return float(dy[under].mean() - dy[corners].mean()), bulge_mm

    faithful_dent, faithful_bulge = dent_and_bulge_mm("faithful")
    fast_dent, _ = dent_and_bulge_mm("fast")
    assert faithful_dent > 2.0
    assert abs(fast_dent) < 0.5
    assert faithful_bulge > 0.2  # squeezed at mid-height, the top face rises


@pytest.mark.parametrize("fidelity", ["fast", "faithful"])
def test_a_mesh_foam_runs_the_compress_procedure_and_reads_back(
    fidelity: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    """At either fidelity: the fast one drives the same tetrahedral mesh by 8 trilinear nodes."""
    stl = _bumpy_sphere_stl(tmp_path / "bumpy.stl")
    out = tmp_path / "run"
    with caplog.at_level(logging.WARNING, logger="absl"):
        code = main(
            [
                "run",
                "compress",
                "--object-mesh",
                str(stl),
                "--fidelity",
                fidelity,
                "--duration",
                "8",  # the calibrated bumpy foam is softer than the flex was: its grasp balances later
                "--out",
                str(out),
                "--no-progress",
            ]
        )
    assert code == 0
    run = open_run(out)
    assert run.status == "complete"
    obj = run.metadata["object"]
    assert obj["shape"] == "mesh" and obj["name"] == "bumpy" and obj["fidelity"] == fidelity
    assert obj["dof"] == ("trilinear" if fidelity == "fast" else "full") and obj["resolution"] == 6
    assert np.allclose(obj["size_m"], [0.06 * 1.0, 0.06, 0.06], atol=0.006)
    assert run.metadata["mujoco_warnings"] == {}
    assert not [r for r in caplog.records if r.name == "absl"]
    assert run.metadata["final_phase"] == "compress"
    assert (run.stream("hand")["torque_nm"][-30:] > 0.05).all()  # the hand holds the mesh foam


@pytest.mark.parametrize(
    ("surface", "words"),
    [
        (b"", "empty"),
        (b"solid x\nendsolid x\n", "no triangles"),
    ],
)
def test_a_bad_mesh_file_is_one_line_and_writes_nothing(tmp_path: Path, surface: bytes, words: str, capsys):
    path = tmp_path / "bad.stl"
    path.write_bytes(surface)
    out = tmp_path / "run"
    assert main(["run", "compress", "--object-mesh", str(path), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("twin: error:") and "\n" not in err and words in err
    assert not out.exists()


def test_a_mesh_too_large_for_the_hand_is_refused_before_meshing(tmp_path: Path):
    stl = _bumpy_sphere_stl(tmp_path / "big.stl", radius_mm=80.0)
    with pytest.raises(ConfigError, match="does not fit in the hand"):
        mesh_object(stl, LIBRARY["block"])
