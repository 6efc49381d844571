"""A run's 3-D scene, pads, contacts and plots, logged in batches (RunRecording sends ROWS_PER_SEND rows
an entity at a time, the parts that do not change with the first row only), read back row for row."""

import warnings
from collections.abc import Mapping

import numpy as np
import pytest
import rerun as rr

from twin.sim.backend import SimBackend
from twin.sim.foam import DEFAULT_OBJECT, LIBRARY
from twin.tactile.layout import LAYOUT
from twin.viz.rerun_log import (
    CONTACTS_ENTITY,
    ROWS_PER_SEND,
    TACTILE_KPA_PER_UNIT,
    RunRecording,
    _as_is,
    _Pending,
    read_rrd_entities,
    read_rrd_images,
    read_rrd_meshes,
    read_rrd_points,
    read_rrd_scalars,
)

FRAMES = ROWS_PER_SEND + 7  # one batch sent during the run, the rest at close


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """The hand and the default foam falling onto the palm, logged at 30 Hz with made-up scans."""
    backend = SimBackend(LIBRARY[DEFAULT_OBJECT], tactile=False)
    model, data = backend.scene()  # the MuJoCo hand with its pads' bodies
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    rng = np.random.default_rng(0)
    kept = {"t": [], "foam": [], "pad_force": [], "pressure": []}
    with RunRecording(path, recording_id="batching") as rec:
        rec.log_model(model)
        for i in range(FRAMES):
            backend.world.advance_to((i + 1) / 30)
            pressure = rng.uniform(0, 150, len(LAYOUT.area_m2))
            pad_force = rng.uniform(0, 5, len(LAYOUT.pads))
            points = rng.uniform(-0.05, 0.05, (i % 4, 3))  # 0 to 3 contacts: ragged rows
            rec.log_tactile(data.time, pressure, pad_force)
            kept["pressure"].append(pressure.copy())
            rec.log_scene(data.time, data)
            rec.log_contacts(data.time, points, np.ones_like(points))
            pressure[:] = -1.0  # the caller's arrays may change once logged
            kept["t"].append(data.time)
            kept["foam"].append(data.flexvert_xpos.copy())
            kept["pad_force"].append(pad_force)
    return path, kept


def test_every_frame_of_the_foam_mesh_has_its_vertices_and_the_triangles(logged):
    path, kept = logged
    meshes = read_rrd_meshes(path, "/world/flex/foam")
    assert len(meshes) == FRAMES
    first_faces = meshes[0][1]
    assert len(first_faces) > 0
    for (verts, faces, normals), foam in zip(meshes, kept["foam"], strict=True):
        np.testing.assert_allclose(verts, foam, atol=1e-6)
        np.testing.assert_array_equal(faces, first_faces)  # sent once, carried forward
        surface = np.unique(faces)
        np.testing.assert_allclose(np.linalg.norm(normals[surface], axis=1), 1, atol=1e-5)
    assert not np.allclose(meshes[0][0], meshes[-1][0])  # the foam moved: each row is its own frame


def test_bodies_pads_and_contacts_have_a_row_a_frame(logged):
    path, _ = logged
    entities = read_rrd_entities(path)
    assert entities["/world/bodies/palm"] == 1  # welded to the world: posed once
    for body in ("f1_outer", "f2_inner", "f3_inner"):
        assert entities[f"/world/bodies/{body}"] == FRAMES
    for pad in LAYOUT.pad_names:  # layout, colour map and scale static, an image a scan
        assert entities[f"/tactile/{pad}"] == FRAMES + 2  # + static: layout and colour map; scale
    assert entities[f"/{CONTACTS_ENTITY}"] == FRAMES
    taxels = read_rrd_points(path, "/world/bodies/palm/taxels_palm")
    assert len(taxels) == FRAMES
    palm = LAYOUT.position_m[LAYOUT.taxels_of("palm")]
    for _, positions, colors in taxels:
        np.testing.assert_allclose(positions, palm, atol=1e-6)  # places sent once, colours every frame
        assert colors.shape == (len(palm), 4)
    assert not np.array_equal(taxels[0][2], taxels[-1][2])


def test_plotted_pad_forces_read_back_as_logged(logged):
    path, kept = logged
    times, forces = read_rrd_scalars(path, "/plots/tactile/pad_force_n")
    np.testing.assert_allclose(times, kept["t"], atol=1e-9)
    np.testing.assert_allclose(forces, kept["pad_force"])


def test_pads_are_images_of_filled_cells_in_kpa(logged):
    """Each pad an image, one pixel a taxel in its grid place as the layout draws it (a finger's first
    row at the bottom, the palm's at the top), its value (on hover) in kPa to 0.1 kPa."""
    path, kept = logged
    for pad in ("palm", "f2_tip"):
        ids = LAYOUT.taxels_of(pad)
        row, col = LAYOUT.row_col[ids].T
        n_rows = row.max() + 1
        if pad != "palm":
            row = n_rows - 1 - row
        images = read_rrd_images(path, f"/tactile/{pad}")
        assert len(images) == FRAMES
        for (t, image), t_kept, pressure in zip(images, kept["t"], kept["pressure"], strict=True):
            assert t == pytest.approx(t_kept)
            assert image.shape == (n_rows, col.max() + 1)
            np.testing.assert_allclose(image[row, col], pressure[ids], atol=TACTILE_KPA_PER_UNIT / 2 + 1e-9)
            left_out = np.ones(image.shape, bool)
            left_out[row, col] = False
            assert (image[left_out] == 0).all()


class _InterruptedRow(Mapping):
    """A row whose value is being read when Ctrl-C lands (KeyboardInterrupt raised from inside `add`)."""

    def __getitem__(self, name):
        raise KeyboardInterrupt

    def __iter__(self):
        return iter(["scalars"])

    def __len__(self):
        return 1


def test_a_ctrl_c_inside_a_pending_row_leaves_no_ragged_column(tmp_path):
    """A run interrupted while a row is being kept: the rows before and after it reach the file whole,
    and Rerun is never handed columns of different lengths (it warns and drops them)."""
    path = tmp_path / "run.rrd"
    rec = rr.RecordingStream("barrett_twin", recording_id="interrupted")
    rec.save(path)
    pending = _Pending(_as_is("plots/test/value", rr.Scalars))
    for k in range(3):
        pending.add(k * 10_000_000, {"scalars": np.array([float(k)])})
    with pytest.raises(KeyboardInterrupt):
        pending.add(30_000_000, _InterruptedRow())
    pending.add(40_000_000, {"scalars": np.array([4.0])})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Rerun's "All columns must have the same length" is a warning
        pending.send(rec)
    rec.flush()
    rec.disconnect()
    t, values = read_rrd_scalars(path, "/plots/test/value")
    np.testing.assert_allclose(t, [0.0, 0.01, 0.02, 0.04])
    np.testing.assert_allclose(values.ravel(), [0.0, 1.0, 2.0, 4.0])
