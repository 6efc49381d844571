"""The 162 taxels sit where the paper says: counts and sizes per pad, on the links' grasping faces."""

import numpy as np

from twin.sim.scene import build_model
from twin.tactile.layout import LAYOUT, PADS, layout_table


def test_pad_counts_and_sizes_follow_the_paper():
    counts = {p.name: len(LAYOUT.taxels_of(p.name)) for p in PADS}
    assert counts == {
        "f1_tip": 22, "f2_tip": 22, "f3_tip": 22,
        "f1_inner": 24, "f2_inner": 24, "f3_inner": 24,
        "palm": 24,
    }  # fmt: skip
    assert len(LAYOUT.area_m2) == 162
    tips_and_inner = LAYOUT.pad_index < 6
    assert np.allclose(LAYOUT.area_m2[tips_and_inner], 36e-6)  # 6 x 6 mm
    assert np.allclose(LAYOUT.area_m2[~tips_and_inner], 100e-6)  # 10 x 10 mm
    assert np.array_equal(LAYOUT.pad_index, np.sort(LAYOUT.pad_index))  # ids run pad by pad


def test_taxels_lie_on_the_grasping_face_of_their_link():
    model = build_model(None)
    for pad in PADS:
        geom = model.geom(f"{pad.body}_collision" if pad.body != "palm" else "palm_plate_collision")
        centre, half = geom.pos, geom.size
        ids = LAYOUT.taxels_of(pad.name)
        pos = LAYOUT.position_m[ids]
        axis = int(np.argmax(np.abs(pad.normal)))
        face = centre[axis] + half[axis]
        assert np.allclose(pos[:, axis], face, atol=1e-4), pad.name
        for other in {0, 1, 2} - {axis}:  # every cell centre within the face's bounds
            assert np.all(np.abs(pos[:, other] - centre[other]) <= half[other] + 1e-9), (pad.name, other)
        assert np.allclose(np.linalg.norm(LAYOUT.normal[ids], axis=1), 1.0)


def test_taxels_do_not_overlap():
    for pad in PADS:
        pos = LAYOUT.position_m[LAYOUT.taxels_of(pad.name)]
        d = np.linalg.norm(pos[:, None] - pos[None], axis=2) + np.eye(len(pos))
        assert d.min() >= pad.pitch_m - 1e-9


def test_grid_puts_values_in_their_cells_and_marks_missing_ones():
    values = np.arange(162, dtype=float)
    tip = LAYOUT.grid("f1_tip", values)
    assert tip.shape == (8, 3) and np.isnan(tip[7, 0]) and np.isnan(tip[7, 2]) and tip[7, 1] == 21
    assert tip[0, 0] == 0 and LAYOUT.grid("palm", values)[5, 3] == 161


def test_layout_table_lists_every_pad():
    table = layout_table()
    assert all(f"| {p.name} |" in table for p in PADS) and "| 22 | 6x6 mm |" in table
