"""Where the 162 taxels are: 7 pads on the BH8's links, each taxel with an id, its pad, its centre and
normal in its link's frame, and its area (paper §5, hardware_facts §4).

The paper fixes element counts and sizes, not the arrangement, so this is our choice (drawn by
`draw_layout`, tabled in docs/tactile_layout.md):
  - fingertip (outer link), 22 taxels of 6x6 mm: 3 across x 8 along the link on its grasping face,
    the two outer cells of the most distal row left out (the pad rounds off towards the tip);
  - inner link, 24 taxels of 6x6 mm: 3 across x 8 along, on the grasping face, towards the distal joint;
  - palm, 24 taxels of 10x10 mm: 6 x 4 on the palm plate, centred.
Ids run pad by pad in the order of PADS, row by row (proximal first), then across.
The grasping face of a finger link is its +y face (the side that turns towards the palm on closing);
the link geometry comes from models/barrett_mjcf/bh8.xml.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from twin.interface.devices import N_TAXELS


@dataclass(frozen=True)
class PadSpec:
    """One pad: a grid of square cells on a plane of its link, some cells possibly left out."""

    name: str
    body: str
    """MuJoCo body the pad is fixed to (bh8.xml)."""
    pitch_m: float
    """Cell size (and centre-to-centre spacing): 6 mm on the fingers, 10 mm on the palm."""
    rows: int
    """Cells along the pad's u axis."""
    cols: int
    """Cells along its v axis."""
    origin_m: tuple[float, float, float]
    """Centre of the first row/column cell, in the body frame."""
    u_axis: tuple[float, float, float]
    """Row direction (proximal -> distal on a finger)."""
    v_axis: tuple[float, float, float]
    normal: tuple[float, float, float]
    """Outward normal of the sensing face."""
    missing: tuple[tuple[int, int], ...] = ()
    """(row, col) cells left out."""

    def cells(self) -> list[tuple[int, int]]:
        """(row, col) of every taxel, in id order."""
        return [(r, c) for r in range(self.rows) for c in range(self.cols) if (r, c) not in self.missing]


_Y = (0.0, 1.0, 0.0)
_X = (1.0, 0.0, 0.0)
_Z = (0.0, 0.0, 1.0)
_FINGER_PITCH = 0.006
_PALM_PITCH = 0.010
# Outer link: box x 0-50 mm, grasping face at y = 7.5 mm, 23 mm wide (z); the tip capsule at x = 50 mm.
_TIP = {"rows": 8, "cols": 3, "origin": (0.005, 0.0075, -0.006), "missing": ((7, 0), (7, 2))}
# Inner link: box x 0-70 mm, grasping face at y = 12.5 mm; the pad covers 17-65 mm.
_INNER = {"rows": 8, "cols": 3, "origin": (0.020, 0.0125, -0.006)}


def _finger_pads(k: int) -> list[PadSpec]:
    return [
        PadSpec(
            name=f"f{k}_tip",
            body=f"f{k}_outer",
            pitch_m=_FINGER_PITCH,
            rows=_TIP["rows"],
            cols=_TIP["cols"],
            origin_m=_TIP["origin"],
            u_axis=_X,
            v_axis=_Z,
            normal=_Y,
            missing=_TIP["missing"],
        ),
        PadSpec(
            name=f"f{k}_inner",
            body=f"f{k}_inner",
            pitch_m=_FINGER_PITCH,
            rows=_INNER["rows"],
            cols=_INNER["cols"],
            origin_m=_INNER["origin"],
            u_axis=_X,
            v_axis=_Z,
            normal=_Y,
        ),
    ]


PADS: tuple[PadSpec, ...] = (
    *(pad for k in (1, 2, 3) for pad in _finger_pads(k) if pad.name.endswith("_tip")),
    *(pad for k in (1, 2, 3) for pad in _finger_pads(k) if pad.name.endswith("_inner")),
    PadSpec(
        name="palm",
        body="palm",
        pitch_m=_PALM_PITCH,
        rows=6,
        cols=4,
        origin_m=(-0.025, -0.015, 0.075),  # palm plate top face at z = 75 mm
        u_axis=_X,
        v_axis=_Y,
        normal=_Z,
    ),
)
"""f1_tip, f2_tip, f3_tip, f1_inner, f2_inner, f3_inner, palm."""
FINGERTIP_PADS = ("f1_tip", "f2_tip", "f3_tip")


@dataclass(frozen=True)
class TactileLayout:
    """All taxels as arrays indexed by taxel id."""

    pads: tuple[PadSpec, ...] = PADS

    @cached_property
    def pad_index(self) -> NDArray[np.int64]:
        """(162,) index into `pads` of each taxel's pad."""
        return np.concatenate([np.full(len(p.cells()), i) for i, p in enumerate(self.pads)])

    @cached_property
    def row_col(self) -> NDArray[np.int64]:
        """(162, 2) row and column of each taxel in its pad's grid."""
        return np.array([rc for p in self.pads for rc in p.cells()])

    @cached_property
    def position_m(self) -> NDArray[np.float64]:
        """(162, 3) taxel centres in their link frames."""
        out = []
        for p in self.pads:
            o, u, v = (np.array(a) for a in (p.origin_m, p.u_axis, p.v_axis))
            out += [o + p.pitch_m * (r * u + c * v) for r, c in p.cells()]
        return np.array(out)

    @cached_property
    def normal(self) -> NDArray[np.float64]:
        """(162, 3) outward normals in their link frames."""
        return np.array([p.normal for p in self.pads for _ in p.cells()], dtype=float)

    @cached_property
    def area_m2(self) -> NDArray[np.float64]:
        """(162,) taxel areas (A_i of eq. 6)."""
        return np.array([p.pitch_m**2 for p in self.pads for _ in p.cells()])

    @property
    def pad_names(self) -> tuple[str, ...]:
        """Pad names in order."""
        return tuple(p.name for p in self.pads)

    def taxels_of(self, pad: str) -> NDArray[np.int64]:
        """Ids of one pad's taxels."""
        return np.flatnonzero(self.pad_index == self.pad_names.index(pad))

    def grid(self, pad: str, values: NDArray) -> NDArray[np.float64]:
        """One pad's values (162,) laid out as its rows x cols image; missing cells are NaN."""
        i = self.pad_names.index(pad)
        spec = self.pads[i]
        img = np.full((spec.rows, spec.cols), np.nan)
        ids = self.taxels_of(pad)
        rc = self.row_col[ids]
        img[rc[:, 0], rc[:, 1]] = np.asarray(values, dtype=float)[ids]
        return img


LAYOUT = TactileLayout()
assert len(LAYOUT.area_m2) == N_TAXELS, "the pads must add up to 162 taxels"


def layout_table() -> str:
    """Markdown table of the pads (what docs/tactile_layout.md shows)."""
    lines = [
        "| pad | link (body) | taxels | cell | grid (rows x cols) | left out | ids | face normal |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for p in LAYOUT.pads:
        ids = LAYOUT.taxels_of(p.name)
        lines.append(
            f"| {p.name} | {p.body} | {len(ids)} | {p.pitch_m * 1e3:.0f}x{p.pitch_m * 1e3:.0f} mm | "
            f"{p.rows} x {p.cols} | {', '.join(map(str, p.missing)) or '-'} | {ids[0]}-{ids[-1]} | "
            f"{'+' if max(p.normal) > 0 else '-'}{'xyz'[int(np.argmax(np.abs(p.normal)))]} |"
        )
    return "\n".join(lines)


def canvas_mm() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where each taxel is drawn in 2-D (mm, y down): (162, 2) centres and (162, 2) half sizes.

    Pads in their real sizes, each finger's fingertip above its inner link, the three fingers side by
    side, the palm below: the arrangement of the Rerun heatmap and the notebooks' plots.
    """
    centers = np.zeros((len(LAYOUT.area_m2), 2))
    half = np.zeros((len(LAYOUT.area_m2), 2))
    for taxel, (row, col) in enumerate(LAYOUT.row_col):
        pad = LAYOUT.pads[LAYOUT.pad_index[taxel]]
        mm = pad.pitch_m * 1e3
        if pad.name == "palm":
            centers[taxel] = (15.0 + col * mm, 10.0 + row * mm)
        else:
            finger = int(pad.name[1]) - 1
            y0 = -110.0 if pad.name.endswith("_tip") else -52.0
            centers[taxel] = (finger * 30.0 + col * mm, y0 + (pad.rows - 1 - row) * mm)
        half[taxel] = 0.45 * mm
    return centers, half


def draw_layout(path: str) -> None:
    """A figure of the 7 pads to scale, every taxel labelled with its id (no pyplot state touched)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    fig = Figure(figsize=(11, 4.5))
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1, 1, 2]})
    groups = {"fingertip (f1_tip)": "f1_tip", "inner link (f1_inner)": "f1_inner", "palm": "palm"}
    for ax, (title, pad) in zip(axes, groups.items(), strict=True):
        spec = LAYOUT.pads[LAYOUT.pad_names.index(pad)]
        mm = spec.pitch_m * 1e3
        for taxel in LAYOUT.taxels_of(pad):
            r, c = LAYOUT.row_col[taxel]
            ax.add_patch(Rectangle((c * mm, r * mm), mm * 0.95, mm * 0.95, fc="#f0be64", ec="k"))
            ax.text((c + 0.47) * mm, (r + 0.47) * mm, str(taxel), ha="center", va="center", fontsize=7)
        ax.set_xlim(-mm * 0.5, (spec.cols + 0.5) * mm)
        ax.set_ylim(-mm * 0.5, (spec.rows + 0.5) * mm)
        ax.set_aspect("equal")
        ax.set_title(f"{title}: {len(LAYOUT.taxels_of(pad))} x {mm:.0f} mm")
        ax.set_xlabel("across (mm)" if pad != "palm" else "palm y (mm)")
        ax.set_ylabel("proximal -> distal (mm)" if pad != "palm" else "palm x (mm)")
    fig.suptitle("Tactile pads (ids; f2/f3 pads are laid out like f1's)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
