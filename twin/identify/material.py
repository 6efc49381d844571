"""From identified contact stiffnesses to the foam's Young's modulus, through a mapping built on the twin.

The stiffness a finger feels is not a material constant: it depends on the object's shape and size
and on where the grasp settles. So the mapping is empirical, built from twin runs of the same
procedure over a grid of moduli and sizes per shape, with two or more noise seeds per point
(experiments/build_material_map.py), and stored with the package (material_map.json).

Its features:
- the grasp closure, the three fingers' summed drive counts over the cycles less the compression's
  offset: how far the hand closes
  to hold the object at the grasp torque, so the indentation measured from the object's undeformed
  size rather than from a detected first contact. It falls steadily with E over the whole grid at
  every size, with no change of regime, and picks the branch where the others fold;
- the grip stiffness, summed distal torques (gauges) against summed drive counts over the cycles: the
  hand's own sensors, steady whichever link or pad carries the load, the steadiest of the three;
- the thumb's (F3) secant stiffness, mean R / mean delta over whole cycles: steep in E on soft foams,
  but on stiff ones it rides on where first contact is placed, which varies run to run;
- the thumb's tangent stiffness, the Kelvin-Voigt k over the 2 mm cycles: erratic on soft foams (the
  clutch may not have broken away), steady to ~1 % on stiff ones.
The thumb's because the thumb alone opposes F1 and F2: its contact neither rocks nor shares load.

Per shape, size and feature: ln E against the feature's coordinate (ln k for a stiffness, minus the
closure), piecewise linear (so monotone) through the grid points
over which k rises with E; between sizes, linear in size. (On a grid 18 % apart in E, a cubic (PCHIP)
interpolant changed no estimate by more than its interval, and costs `twin identify` a 0.3 s import.)
Each feature's variance in ln E is the curve's leave-one-out error plus its run-to-run spread (seeds)
and the fit's own uncertainty, both carried through the curve's slope; features are combined by
inverse variance, the interval widened by the Birge ratio when they disagree. A feature whose stiffness
lies on a folded stretch of its curve (reached also outside the valid range) is ambiguous, and joins
only when the unambiguous features agree with its valid branch.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from twin.interface.errors import TwinError

MAP_FILE = Path(__file__).with_name("material_map.json")
FEATURES = {
    "thumb_secant_n_m": "F3 secant contact stiffness: mean R / mean delta over whole cycles (N/m)",
    "thumb_tangent_n_m": "F3 tangent contact stiffness: Kelvin-Voigt k over the cycles (N/m)",
    "grip_nm_per_kcount": "summed distal torques (gauges) against summed drive counts over the cycles "
    "(N*m per 1000 counts)",
    "grasp_closure_kcounts": "summed drive counts of the three fingers over the cycles, less the "
    "compression's offset (1000 counts): how far the hand closes on the object at the grasp torque; "
    "falls as E rises",
}
FALLING = frozenset({"grasp_closure_kcounts"})
"""Features that fall as E rises: their coordinate is minus the value (the others' is ln k)."""
MIN_POINTS = 5
EXTRAPOLATION_SIGMA_PER_REACH = 0.5
"""Beyond its valid range a curve is extended along its end segment, which the grasp's regime change
there does not follow: each unit of ln E it reaches past the range adds half a unit to its 1-sigma. On
fresh 70 mm soft spheres the thumb's secant, extrapolated 0.22 and 0.68 past its range, was off by
0.19 and 0.13 in ln E, outside intervals that did not grow with the reach."""
Z95 = 1.96
NOISE_SMOOTHING_KNOTS = 5
"""Run-to-run spread from two seeds is itself noisy: pooled (RMS) over this many neighbouring knots,
so one knot where the runs split (a clutch that breaks away in one seed only) widens its neighbourhood."""
FOLD_MARGIN_LOG = float(np.log(1.15))
FOLD_MARGIN_SIGMAS = 3.0
"""A knot outside a curve's valid range marks as folded the stiffnesses within max(3 sigma of its own
seeds, 15 %) of it: between knots and from run to run a regime is only sampled there. The 65 mm
sphere's folded-finger grip read 0.79-0.83 over six seeds at 8 kPa, and 0.85 in an unseen run at
11.5 kPa, which the unmargined fold missed, so that run's grip passed as clear at 144 kPa. On the
closure's coordinate (thousands of counts) the same margins apply; its curves have no fold."""


class MappingError(TwinError, ValueError):
    """No mapping covers the object (shape unknown, size or stiffness outside the built range)."""


@dataclass(frozen=True)
class Curve:
    """ln E as a monotone interpolant of the feature's coordinate x (coordinate()) for one shape, size
    and feature."""

    size_m: float
    feature: str
    knots_x: tuple[float, ...]
    knots_log_e: tuple[float, ...]
    knots_noise_x: tuple[float, ...]
    """Run-to-run standard deviation of x at each knot (0 where one seed was run)."""
    loo_rms_log: float
    """Leave-one-out RMS error of ln E over the grid (interior points)."""
    young_range_pa: tuple[float, float]
    """Moduli over which the sweep's stiffness rose monotonically: where the curve is valid."""
    folded_x: tuple[tuple[float, float], ...] = ()
    """x intervals that the sweep reached outside the valid range (where the stiffness falls again, or
    rose from a softer regime), inside the range or beyond its far end: a stiffness there has two
    moduli, so it is ambiguous."""

    folded_young_pa: tuple[tuple[float, float], ...] = ()
    """Per folded interval, the moduli of the grid's branch outside the valid range that reached it."""

    def is_folded(self, x: float) -> bool:
        """Whether a value here is also reached outside the valid range."""
        return any(lo < x < hi for lo, hi in self.folded_x)

    def other_branch_pa(self, x: float) -> tuple[float, float] | None:
        """The moduli outside the valid range that may also read this value (None: none)."""
        hits = [e for (lo, hi), e in zip(self.folded_x, self.folded_young_pa, strict=False) if lo < x < hi]
        return (min(e[0] for e in hits), max(e[1] for e in hits)) if hits else None

    @property
    def x_range(self) -> tuple[float, float]:
        """The coordinate's range over the grid."""
        return self.knots_x[0], self.knots_x[-1]

    def log_e(self, x: float) -> float:
        """ln E at x (the end segments extended beyond the grid)."""
        return _interp(x, self.knots_x, self.knots_log_e)

    def slope(self, x: float) -> float:
        """d ln E / dx of the segment at x."""
        xs, y = self.knots_x, self.knots_log_e
        i = int(np.clip(np.searchsorted(xs, x) - 1, 0, len(xs) - 2))
        return (y[i + 1] - y[i]) / (xs[i + 1] - xs[i])

    def noise_x(self, x: float) -> float:
        """Run-to-run spread of x here (linear between knots, held beyond them)."""
        return float(np.interp(x, self.knots_x, self.knots_noise_x))

    def to_json(self) -> dict:
        """Plain-JSON form."""
        return {
            "size_m": self.size_m,
            "feature": self.feature,
            "knots_x": list(self.knots_x),
            "knots_log_e": list(self.knots_log_e),
            "knots_noise_x": list(self.knots_noise_x),
            "loo_rms_log": self.loo_rms_log,
            "young_range_pa": list(self.young_range_pa),
            "folded_x": [list(f) for f in self.folded_x],
            "folded_young_pa": [list(f) for f in self.folded_young_pa],
        }

    @classmethod
    def from_json(cls, c: dict) -> Curve:
        """Inverse of to_json."""
        return cls(
            size_m=float(c["size_m"]),
            feature=str(c["feature"]),
            knots_x=tuple(map(float, c["knots_x"])),
            knots_log_e=tuple(map(float, c["knots_log_e"])),
            knots_noise_x=tuple(map(float, c["knots_noise_x"])),
            loo_rms_log=float(c["loo_rms_log"]),
            young_range_pa=(float(c["young_range_pa"][0]), float(c["young_range_pa"][1])),
            folded_x=tuple((float(lo), float(hi)) for lo, hi in c.get("folded_x", [])),
            folded_young_pa=tuple((float(lo), float(hi)) for lo, hi in c.get("folded_young_pa", [])),
        )


@dataclass(frozen=True)
class MaterialEstimate:
    """E with a 95 % confidence interval, and what each feature said."""

    young_pa: float
    ci95_pa: tuple[float, float]
    shape: str
    size_m: float
    extrapolated: bool
    components: list[dict] = field(default_factory=list)
    branch_unsettled: bool = False
    """Every feature used is on a folded stretch and nothing picked its branch: the interval covers
    the other branch's moduli too."""

    def to_json(self) -> dict:
        """Plain-JSON form for the results file."""
        return {
            "young_pa": self.young_pa,
            "ci95_pa": list(self.ci95_pa),
            "shape": self.shape,
            "size_m": self.size_m,
            "extrapolated": self.extrapolated,
            "branch_unsettled": self.branch_unsettled,
            "features": self.components,
        }


def coordinate(feature: str, value: float | np.ndarray) -> np.ndarray:
    """The curve's abscissa for a feature value, rising with E: ln k for a stiffness (NaN where k is
    not positive), minus the value for a falling feature (the closure)."""
    v = np.asarray(value, dtype=float)
    if feature in FALLING:
        return -v
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(v > 0, np.log(np.where(v > 0, v, 1.0)), np.nan)


def coordinate_sigma(feature: str, value: float, sigma: float) -> float:
    """A value's 1-sigma on the coordinate (relative for a stiffness); 0 where not finite."""
    if not math.isfinite(sigma):
        return 0.0
    return float(sigma) if feature in FALLING else float(sigma / value)


def knot_value(feature: str, values: list[float]) -> float:
    """One grid point's value over its seeds: the mean on the coordinate (geometric for a stiffness);
    NaN if any seed has no value (that grid point breaks the curve)."""
    x = coordinate(feature, values)
    if not np.isfinite(x).all():
        return math.nan
    m = float(np.mean(x))
    return -m if feature in FALLING else math.exp(m)


def _combine(parts: list[dict]) -> tuple[float, float]:
    """Inverse-variance mean of the parts' ln E and its 1-sigma, widened by the Birge ratio when they
    disagree beyond their sigmas."""
    w = np.array([1.0 / p["sigma_log"] ** 2 for p in parts])
    mu = np.array([p["log_e"] for p in parts])
    log_e = float(np.sum(w * mu) / np.sum(w))
    sigma = math.sqrt(1.0 / np.sum(w))
    if len(parts) > 1:
        chi2 = float(np.sum(w * (mu - log_e) ** 2)) / (len(parts) - 1)
        sigma *= max(1.0, math.sqrt(chi2))
    return log_e, sigma


def _interp(x0: float, x: np.ndarray | tuple, y: np.ndarray | tuple) -> float:
    """Piecewise-linear interpolation, the end segments extended beyond the knots."""
    xs, ys = np.asarray(x, float), np.asarray(y, float)
    i = int(np.clip(np.searchsorted(xs, x0) - 1, 0, len(xs) - 2))
    return float(ys[i] + (ys[i + 1] - ys[i]) * (x0 - xs[i]) / (xs[i + 1] - xs[i]))


def monotone_span(young_pa: np.ndarray, x: np.ndarray) -> slice:
    """The longest run of grid points (in E order) over which the coordinate is finite and strictly rises."""
    k = np.asarray(x, float)[np.argsort(young_pa)]
    best, start = (0, 0), 0
    for i in range(len(k) + 1):
        if i == len(k) or not np.isfinite(k[i]) or (i > start and not k[i] > k[i - 1]):
            if i - start > best[1] - best[0]:
                best = (start, i)
            start = i if i < len(k) and np.isfinite(k[i]) else i + 1
    return slice(*best)


def fit_curve(
    size_m: float,
    values: np.ndarray,
    young_pa: np.ndarray,
    noise_x: np.ndarray | None = None,
    feature: str = "thumb_secant_n_m",
) -> Curve:
    """One size's curve over the monotone part of its grid, with its leave-one-out error there.

    `values` per grid modulus (knot_value over the seeds); `noise_x` the seeds' standard deviation of
    the coordinate there (None: one seed)."""
    order = np.argsort(young_pa)
    young, x = np.asarray(young_pa, float)[order], coordinate(feature, np.asarray(values, float)[order])
    noise = np.zeros_like(x) if noise_x is None else np.nan_to_num(np.asarray(noise_x, float)[order])
    span = monotone_span(young, x)
    folded = _folded(x, span, noise, young)
    young, x, noise = young[span], x[span], noise[span]
    if len(young) < MIN_POINTS:
        raise MappingError(
            f"{size_m * 1e3:.0f} mm, {feature}: the value moves monotonically with E over only "
            f"{len(young)} grid "
            "points; cannot map"
        )
    half = NOISE_SMOOTHING_KNOTS // 2
    noise = np.array(
        [np.sqrt(np.mean(noise[max(0, i - half) : i + half + 1] ** 2)) for i in range(len(noise))]
    )
    y = np.log(young)
    errors = []
    for i in range(1, len(x) - 1):
        keep = np.arange(len(x)) != i
        errors.append(_interp(x[i], x[keep], y[keep]) - y[i])
    return Curve(
        size_m=float(size_m),
        feature=feature,
        knots_x=tuple(map(float, x)),
        knots_log_e=tuple(map(float, y)),
        knots_noise_x=tuple(map(float, noise)),
        loo_rms_log=float(np.sqrt(np.mean(np.square(errors)))),
        young_range_pa=(float(young[0]), float(young[-1])),
        folded_x=tuple(f for f, _ in folded),
        folded_young_pa=tuple(e for _, e in folded),
    )


def _folded(
    x: np.ndarray, span: slice, noise_x: np.ndarray, young: np.ndarray
) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """Coordinate intervals that the grid reaches outside the span (x in E order) and that the span's own
    branch also claims: its range, and beyond it on the far side. Each side's branch runs continuously
    from the span's end knot through its own points, and each of its points reaches FOLD_MARGIN beyond
    its own value.

    Beyond the far side: softer foams reading stiffer than the stiffest valid knot (fingers folded over
    a soft sphere: the 65 mm grip read 1.7 N*m per 1000 counts at 11 kPa, above the 1.58 of 360 kPa) are
    as ambiguous as inside the range; the valid branch extrapolated would claim them too. On the near
    side (a soft foam softer than the softest valid knot) the two branches agree on the direction.
    Each interval comes with the moduli of the branch that reached it, up to the span's end knot."""
    inside = x[span]
    lo, hi = float(inside[0]), float(inside[-1])
    out = []
    sides = (
        (slice(0, span.start), lo, lo, math.inf, (young[0], young[span.start])),
        (slice(span.stop, len(x)), hi, -math.inf, hi, (young[span.stop - 1], young[-1])),
    )
    for side, end, floor, ceiling, moduli in sides:
        branch, noise = x[side], noise_x[side]
        seen = np.isfinite(branch)
        margin = np.maximum(FOLD_MARGIN_SIGMAS * noise[seen], FOLD_MARGIN_LOG)
        reached = np.concatenate([branch[seen] - margin, branch[seen] + margin, [end]])
        a, b = max(float(reached.min()), floor), min(float(reached.max()), ceiling)
        if b - a > 1e-12:
            out.append(((a, b), (float(moduli[0]), float(moduli[1]))))
    return out


def _union(ranges: list[tuple[float, float] | None]) -> list[float] | None:
    """The smallest range holding every given one (None: none given)."""
    given = [r for r in ranges if r]
    return [min(r[0] for r in given), max(r[1] for r in given)] if given else None


def _contradicts(other: dict, part: dict) -> bool:
    """`other` refutes `part`'s valid branch: at `part`'s modulus `other` would be on its own valid
    branch, yet its estimate disagrees with `part`'s beyond their joint 95 % interval."""
    lo, hi = other["valid_log_e"]
    apart = abs(part["log_e"] - other["log_e"])
    return lo <= part["log_e"] <= hi and apart > Z95 * math.hypot(part["sigma_log"], other["sigma_log"])


def _why_left_out(part: dict, log_e: float) -> str:
    """Why a feature is not in the estimate at ln E, in words for `twin identify`."""
    if part["extrapolated"]:
        return "outside its valid range"
    lo, hi = part["valid_log_e"]
    if part["ambiguous"] and not lo <= log_e <= hi:
        return "on a folded stretch of its curve, off the branch the estimate is on"
    return "refuted: the features used would read its modulus otherwise"


def _consistent(inside: list[dict]) -> list[dict]:
    """The features that hold together: the most refuted one left out, one at a time, until none refutes
    another (used on the clear features, on every in-range one when nothing referees, and on those
    used once the ambiguous ones have joined).

    A folded grip on a soft 70 mm sphere reads what its valid branch puts at twice the modulus; that
    modulus lies inside the thumb's valid ranges, where the thumb's pad would read it too, and does
    not: the grip is refuted. The thumb's own estimate lies below the grip's valid range, where a
    folded grip is what one expects: it stands.

    The feature most refuted goes first, then the others are judged again without it: between sizes the
    thumb's secant read 20-45 % soft while three features agreed, and refuted each of them as they
    refuted it. Where several are refuted by equally many, nothing picks one out: all of them stay,
    and the Birge ratio widens the interval (a 70 mm, 249 kPa sphere's grip and secant refuted each
    other; leaving both out put the estimate on the tangent and the closure, -12 %)."""
    kept = list(inside)
    while True:
        refuted = [sum(_contradicts(o, p) for o in kept if o is not p) for p in kept]
        worst = max(refuted, default=0)
        if worst == 0 or refuted.count(worst) > 1:
            return kept
        kept.pop(refuted.index(worst))


def _between(a: Curve, b: Curve, size_m: float) -> Curve | None:
    """The curve at a size between a's and b's, linear in size at fixed E, over the moduli both are
    valid over (None: fewer than two knots there). At fixed E rather than at fixed stiffness: the
    grasp closure at a fixed E moves steadily with size, while the moduli it reads at a fixed value
    do not (fixed stiffness put 66-69 mm spheres' closure up to 25 % stiff)."""
    w = (size_m - a.size_m) / (b.size_m - a.size_m)
    lo, hi = max(a.knots_log_e[0], b.knots_log_e[0]), min(a.knots_log_e[-1], b.knots_log_e[-1])
    log_e = np.unique(np.concatenate([a.knots_log_e, b.knots_log_e]))
    log_e = log_e[(log_e >= lo - 1e-12) & (log_e <= hi + 1e-12)]
    if len(log_e) < 2:
        return None

    def mix(values_a: tuple[float, ...], values_b: tuple[float, ...]) -> tuple[float, ...]:
        at_a, at_b = np.interp(log_e, a.knots_log_e, values_a), np.interp(log_e, b.knots_log_e, values_b)
        return tuple(map(float, (1 - w) * at_a + w * at_b))

    folds = [(f, e) for c in (a, b) for f, e in zip(c.folded_x, c.folded_young_pa, strict=False)]
    return Curve(
        size_m=float(size_m),
        feature=a.feature,
        knots_x=mix(a.knots_x, b.knots_x),
        knots_log_e=tuple(map(float, log_e)),
        knots_noise_x=mix(a.knots_noise_x, b.knots_noise_x),
        loo_rms_log=(1 - w) * a.loo_rms_log + w * b.loo_rms_log,
        young_range_pa=(math.exp(log_e[0]), math.exp(log_e[-1])),
        folded_x=tuple(f for f, _ in folds),
        folded_young_pa=tuple(e for _, e in folds),
    )


@dataclass(frozen=True)
class MaterialMap:
    """Curves per shape (any sizes and features)."""

    curves: dict[str, list[Curve]]
    provenance: dict

    @classmethod
    def load(cls, path: Path = MAP_FILE) -> MaterialMap:
        """Read the stored mapping."""
        try:
            raw = json.loads(Path(path).read_text())
            curves = {
                shape: sorted((Curve.from_json(c) for c in cs), key=lambda c: (c.feature, c.size_m))
                for shape, cs in raw["curves"].items()
            }
        except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
            raise MappingError(
                f"{path}: not a readable material mapping ({type(exc).__name__}: {exc})"
            ) from None
        return cls(curves=curves, provenance=raw.get("provenance", {}))

    def save(self, path: Path = MAP_FILE) -> Path:
        """Write the mapping as JSON."""
        raw = {
            "features": FEATURES,
            "model": "ln E piecewise linear in ln k per shape, size and feature; linear in size; "
            "features by inverse variance",
            "provenance": self.provenance,
            "curves": {shape: [c.to_json() for c in cs] for shape, cs in self.curves.items()},
        }
        Path(path).write_text(json.dumps(raw, indent=1) + "\n")
        return Path(path)

    def sizes(self, shape: str, feature: str) -> list[float]:
        """Sizes (m) with a curve for this shape and feature."""
        return sorted(c.size_m for c in self.curves.get(shape, []) if c.feature == feature)

    def coverage(self) -> str:
        """One line: which shapes and sizes the mapping covers."""
        out = []
        for shape, cs in sorted(self.curves.items()):
            sizes = sorted({c.size_m for c in cs})
            out.append(f"{shape} {sizes[0] * 1e3:.0f}-{sizes[-1] * 1e3:.0f} mm")
        return "; ".join(out)

    def estimate(
        self, shape: str, size_m: float, features: Mapping[str, tuple[float, float]]
    ) -> MaterialEstimate:
        """E (Pa) and its 95 % interval for an object of this shape and size (its largest extent), from
        feature values and their own 1-sigma: {feature: (k_n_m, sigma_n_m)}."""
        if shape not in self.curves:
            raise MappingError(
                f"no material mapping for shape '{shape}' (the mapping covers {self.coverage()})"
            )
        parts = []
        for feature, (k, k_sigma) in features.items():
            part = self._feature_estimate(shape, size_m, feature, k, k_sigma)
            if part is not None:
                parts.append(part)
        if not parts:
            sizes = sorted({c.size_m for c in self.curves[shape]})
            raise MappingError(
                f"{shape} of {size_m * 1e3:.0f} mm: no feature maps here (sizes {sizes[0] * 1e3:.0f}-"
                f"{sizes[-1] * 1e3:.0f} mm, positive stiffness needed)"
            )
        inside = [p for p in parts if not p["extrapolated"]]
        # Clear features that the other clear ones refute are left out too (_consistent): on a 65 mm,
        # 11.1 kPa sphere the thumb's tangent read 19.6 kPa, inside the secant's valid range, where the
        # secant would read it; the secant read 11.7 kPa, below the tangent's range (from 15.5 kPa),
        # where the tangent is erratic. Combined they said +21 %; the secant alone +5 %.
        unambiguous = [p for p in inside if not p["ambiguous"]]
        clear = _consistent(unambiguous)
        # An ambiguous feature has a second modulus outside its valid range. It joins when the
        # unambiguous features place the foam inside that range, i.e. on its valid branch: the clear
        # ones, or failing those the ones outside their own valid range (a thumb below its range says
        # the foam is softer than the grip's valid branch; the 67.5 mm sphere at 11 kPa read +81 % on
        # the grip's alone). Inside the range, not within the referees' interval: a clear feature
        # that is off by its own noise must not push a precise one out. Referees outside their range
        # only pick the branch: their own value is an extrapolation (a 70 mm thumb secant below its
        # range read 17.5 kPa on a 13.1 kPa sphere whose in-range tangent said 13.2), so the in-range
        # features they admit carry the estimate.
        referees = clear or [p for p in parts if p["extrapolated"] and not p["ambiguous"]]
        used = _consistent(inside) or parts
        if referees:
            log_e, _ = _combine(referees)
            joined = [
                p for p in inside if p["ambiguous"] and p["valid_log_e"][0] <= log_e <= p["valid_log_e"][1]
            ]
            used = clear + joined if clear else (joined or referees)
            # The joined features, now on their valid branch, are witnesses too: between sizes the
            # thumb's secant and the closure, the only clear ones, refuted each other, and the grip and
            # tangent sided with the closure.
            used = _consistent(used)
        log_e, sigma = _combine(used)
        low, high = log_e - Z95 * sigma, log_e + Z95 * sigma
        unsettled = not referees and all(p["ambiguous"] for p in used)
        if unsettled:  # nothing says which branch: the interval takes in the other one as well
            others = [p["other_branch_pa"] for p in used if p["other_branch_pa"]]
            low = min([low, *(math.log(o[0]) for o in others)])
            high = max([high, *(math.log(o[1]) for o in others)])
        for p in parts:
            p["used"] = p in used
            p["left_out"] = None if p["used"] else _why_left_out(p, log_e)
            p["young_pa"] = math.exp(p.pop("log_e"))
            p["valid_range_pa"] = [math.exp(v) for v in p.pop("valid_log_e")]
        return MaterialEstimate(
            young_pa=math.exp(log_e),
            ci95_pa=(math.exp(low), math.exp(high)),
            shape=shape,
            size_m=size_m,
            extrapolated=all(p["extrapolated"] for p in used),
            components=parts,
            branch_unsettled=unsettled,
        )

    def _feature_estimate(
        self, shape: str, size_m: float, feature: str, k: float, k_sigma: float
    ) -> dict | None:
        x = float(coordinate(feature, k))
        c = self.curve_at(shape, feature, size_m)
        if c is None or not math.isfinite(x):
            return None
        log_e = c.log_e(x)
        valid_log_e = (math.log(c.young_range_pa[0]), math.log(c.young_range_pa[1]))
        reach = max(0.0, valid_log_e[0] - log_e, log_e - valid_log_e[1])
        sigma_log = math.sqrt(
            c.loo_rms_log**2
            + c.slope(x) ** 2 * (c.noise_x(x) ** 2 + coordinate_sigma(feature, k, k_sigma) ** 2)
            + (EXTRAPOLATION_SIGMA_PER_REACH * reach) ** 2
        )
        return {
            "feature": feature,
            "value": k,
            "log_e": log_e,
            "valid_log_e": valid_log_e,
            "sigma_log": max(sigma_log, 1e-6),
            "extrapolated": not (c.x_range[0] <= x <= c.x_range[1]),
            "ambiguous": c.is_folded(x),
            "other_branch_pa": c.other_branch_pa(x),
        }

    def curve_at(self, shape: str, feature: str, size_m: float) -> Curve | None:
        """The feature's curve at this size: a stored one, or between two stored sizes the curve linear
        in size at fixed E, its error widened by how far the stored sizes themselves are from that
        (size_error_log), most at the midpoint. None: outside the sizes, or no moduli both neighbours
        are valid over."""
        curves = self._curves(shape, feature)
        if not curves or not curves[0].size_m - 1e-6 <= size_m <= curves[-1].size_m + 1e-6:
            return None
        near = [c for c in curves if abs(c.size_m - size_m) <= 1e-6]
        if near:
            return near[0]
        j = int(np.searchsorted([c.size_m for c in curves], size_m)) - 1
        a, b = curves[j], curves[j + 1]
        curve = _between(a, b, size_m)
        if curve is None:
            return None
        w = (size_m - a.size_m) / (b.size_m - a.size_m)
        ends = [
            e for e in (self.size_error_log(shape, feature, c.size_m) for c in (a, b)) if math.isfinite(e)
        ]
        size_error = 4 * w * (1 - w) * max(ends, default=0.0)
        return replace(curve, loo_rms_log=math.hypot(curve.loo_rms_log, size_error))

    def size_error_log(self, shape: str, feature: str, size_m: float) -> float:
        """RMS error in ln E of the curve at a stored size as predicted from its two neighbouring sizes
        without it (leave one size out); NaN at the end sizes.

        Between sizes a feature need not move smoothly: the thumb's secant, read between 67.5 and
        70 mm, came out 20-45 % soft on 68.75 mm spheres; left out, the 70 mm curve is 0.41 away from
        what 67.5 and 75 mm predict, the grip's 0.08."""
        curves = self._curves(shape, feature)
        i = next((i for i, c in enumerate(curves) if abs(c.size_m - size_m) <= 1e-6), None)
        if i is None or i == 0 or i == len(curves) - 1:
            return math.nan
        mid = curves[i]
        guess = _between(curves[i - 1], curves[i + 1], mid.size_m)
        if guess is None:
            return math.nan
        errors = [
            guess.log_e(x) - y
            for x, y in zip(mid.knots_x, mid.knots_log_e, strict=True)
            if guess.x_range[0] <= x <= guess.x_range[1]
        ]
        return float(np.sqrt(np.mean(np.square(errors)))) if errors else math.nan

    def _curves(self, shape: str, feature: str) -> list[Curve]:
        return sorted((c for c in self.curves.get(shape, []) if c.feature == feature), key=lambda c: c.size_m)
