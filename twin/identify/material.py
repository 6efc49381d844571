"""From identified contact stiffnesses to the foam's Young's modulus, through a mapping built on the twin.

The stiffness a finger feels is not a material constant: it depends on the object's shape and size
and on where the grasp settles. So the mapping is empirical, built from twin runs of the same
procedure over a grid of moduli and sizes per shape, with two or more noise seeds per point
(experiments/build_material_map.py), and stored with the package (material_map.json).

Its features:
- the grip stiffness, summed distal torques (gauges) against summed drive counts over the cycles: the
  hand's own sensors, steady whichever link or pad carries the load, the steadiest of the three;
- the thumb's (F3) secant stiffness, mean R / mean delta over whole cycles: steep in E on soft foams,
  but on stiff ones it rides on where first contact is placed, which varies run to run;
- the thumb's tangent stiffness, the Kelvin-Voigt k over the 2 mm cycles: erratic on soft foams (the
  clutch may not have broken away), steady to ~1 % on stiff ones.
The thumb's because the thumb alone opposes F1 and F2: its contact neither rocks nor shares load.

Per shape, size and feature: ln E against ln k, piecewise linear (so monotone) through the grid points
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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twin.interface.errors import TwinError

MAP_FILE = Path(__file__).with_name("material_map.json")
FEATURES = {
    "thumb_secant_n_m": "F3 secant contact stiffness: mean R / mean delta over whole cycles (N/m)",
    "thumb_tangent_n_m": "F3 tangent contact stiffness: Kelvin-Voigt k over the cycles (N/m)",
    "grip_nm_per_kcount": "summed distal torques (gauges) against summed drive counts over the cycles "
    "(N*m per 1000 counts)",
}
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
11.5 kPa, which the unmargined fold missed, so that run's grip passed as clear at 144 kPa."""


class MappingError(TwinError, ValueError):
    """No mapping covers the object (shape unknown, size or stiffness outside the built range)."""


@dataclass(frozen=True)
class Curve:
    """ln E as a monotone interpolant of ln k for one shape, size and feature."""

    size_m: float
    feature: str
    knots_log_k: tuple[float, ...]
    knots_log_e: tuple[float, ...]
    knots_noise_log_k: tuple[float, ...]
    """Run-to-run standard deviation of ln k at each knot (0 where one seed was run)."""
    loo_rms_log: float
    """Leave-one-out RMS error of ln E over the grid (interior points)."""
    young_range_pa: tuple[float, float]
    """Moduli over which the sweep's stiffness rose monotonically: where the curve is valid."""
    folded_log_k: tuple[tuple[float, float], ...] = ()
    """ln k intervals that the sweep reached outside the valid range (where the stiffness falls again, or
    rose from a softer regime), inside the range or beyond its far end: a stiffness there has two
    moduli, so it is ambiguous."""

    folded_young_pa: tuple[tuple[float, float], ...] = ()
    """Per folded interval, the moduli of the grid's branch outside the valid range that reached it."""

    def is_folded(self, log_k: float) -> bool:
        """Whether a stiffness here is also reached outside the valid range."""
        return any(lo < log_k < hi for lo, hi in self.folded_log_k)

    def other_branch_pa(self, log_k: float) -> tuple[float, float] | None:
        """The moduli outside the valid range that may also read this stiffness (None: none)."""
        hits = [
            e for (lo, hi), e in zip(self.folded_log_k, self.folded_young_pa, strict=False) if lo < log_k < hi
        ]
        return (min(e[0] for e in hits), max(e[1] for e in hits)) if hits else None

    @property
    def log_k_range(self) -> tuple[float, float]:
        """The stiffness range of the grid (ln N/m)."""
        return self.knots_log_k[0], self.knots_log_k[-1]

    def log_e(self, log_k: float) -> float:
        """ln E at ln k (the end segments extended beyond the grid)."""
        return _interp(log_k, self.knots_log_k, self.knots_log_e)

    def slope(self, log_k: float) -> float:
        """d ln E / d ln k of the segment at ln k."""
        x, y = self.knots_log_k, self.knots_log_e
        i = int(np.clip(np.searchsorted(x, log_k) - 1, 0, len(x) - 2))
        return (y[i + 1] - y[i]) / (x[i + 1] - x[i])

    def noise_log_k(self, log_k: float) -> float:
        """Run-to-run spread of ln k here (linear between knots, held beyond them)."""
        return float(np.interp(log_k, self.knots_log_k, self.knots_noise_log_k))

    def to_json(self) -> dict:
        """Plain-JSON form."""
        return {
            "size_m": self.size_m,
            "feature": self.feature,
            "knots_log_k": list(self.knots_log_k),
            "knots_log_e": list(self.knots_log_e),
            "knots_noise_log_k": list(self.knots_noise_log_k),
            "loo_rms_log": self.loo_rms_log,
            "young_range_pa": list(self.young_range_pa),
            "folded_log_k": [list(f) for f in self.folded_log_k],
            "folded_young_pa": [list(f) for f in self.folded_young_pa],
        }

    @classmethod
    def from_json(cls, c: dict) -> Curve:
        """Inverse of to_json."""
        return cls(
            size_m=float(c["size_m"]),
            feature=str(c["feature"]),
            knots_log_k=tuple(map(float, c["knots_log_k"])),
            knots_log_e=tuple(map(float, c["knots_log_e"])),
            knots_noise_log_k=tuple(map(float, c["knots_noise_log_k"])),
            loo_rms_log=float(c["loo_rms_log"]),
            young_range_pa=(float(c["young_range_pa"][0]), float(c["young_range_pa"][1])),
            folded_log_k=tuple((float(lo), float(hi)) for lo, hi in c.get("folded_log_k", [])),
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


def monotone_span(young_pa: np.ndarray, stiffness_n_m: np.ndarray) -> slice:
    """The longest run of grid points (in E order) over which the stiffness is positive and strictly rises."""
    k = np.asarray(stiffness_n_m, float)[np.argsort(young_pa)]
    best, start = (0, 0), 0
    for i in range(len(k) + 1):
        if i == len(k) or not k[i] > 0 or (i > start and not k[i] > k[i - 1]):
            if i - start > best[1] - best[0]:
                best = (start, i)
            start = i if i < len(k) and k[i] > 0 else i + 1
    return slice(*best)


def fit_curve(
    size_m: float,
    stiffness_n_m: np.ndarray,
    young_pa: np.ndarray,
    noise_log_k: np.ndarray | None = None,
    feature: str = "thumb_secant_n_m",
) -> Curve:
    """One size's curve over the monotone part of its grid, with its leave-one-out error there.

    `stiffness_n_m` per grid modulus (the geometric mean over seeds); `noise_log_k` the seeds'
    standard deviation of ln k there (None: one seed)."""
    order = np.argsort(young_pa)
    young, k = np.asarray(young_pa, float)[order], np.asarray(stiffness_n_m, float)[order]
    noise = np.zeros_like(k) if noise_log_k is None else np.nan_to_num(np.asarray(noise_log_k, float)[order])
    span = monotone_span(young, k)
    folded = _folded(k, span, noise, young)
    young, k, noise = young[span], k[span], noise[span]
    if len(young) < MIN_POINTS:
        raise MappingError(
            f"{size_m * 1e3:.0f} mm, {feature}: the stiffness rises monotonically over only "
            f"{len(young)} grid "
            "points; cannot map"
        )
    half = NOISE_SMOOTHING_KNOTS // 2
    noise = np.array(
        [np.sqrt(np.mean(noise[max(0, i - half) : i + half + 1] ** 2)) for i in range(len(noise))]
    )
    x, y = np.log(k), np.log(young)
    errors = []
    for i in range(1, len(x) - 1):
        keep = np.arange(len(x)) != i
        errors.append(_interp(x[i], x[keep], y[keep]) - y[i])
    return Curve(
        size_m=float(size_m),
        feature=feature,
        knots_log_k=tuple(map(float, x)),
        knots_log_e=tuple(map(float, y)),
        knots_noise_log_k=tuple(map(float, noise)),
        loo_rms_log=float(np.sqrt(np.mean(np.square(errors)))),
        young_range_pa=(float(young[0]), float(young[-1])),
        folded_log_k=tuple(f for f, _ in folded),
        folded_young_pa=tuple(e for _, e in folded),
    )


def _folded(
    k: np.ndarray, span: slice, noise_log_k: np.ndarray, young: np.ndarray
) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """ln k intervals that the grid reaches outside the span (k in E order) and that the span's own
    branch also claims: its range, and beyond it on the far side. Each side's branch runs continuously
    from the span's end knot through its own points, and each of its points reaches FOLD_MARGIN beyond
    its own value.

    Beyond the far side: softer foams reading stiffer than the stiffest valid knot (fingers folded over
    a soft sphere: the 65 mm grip read 1.7 N*m per 1000 counts at 11 kPa, above the 1.58 of 360 kPa) are
    as ambiguous as inside the range; the valid branch extrapolated would claim them too. On the near
    side (a soft foam softer than the softest valid knot) the two branches agree on the direction.
    Each interval comes with the moduli of the branch that reached it, up to the span's end knot."""
    inside = k[span]
    lo, hi = float(np.log(inside[0])), float(np.log(inside[-1]))
    out = []
    sides = (
        (slice(0, span.start), inside[0], lo, math.inf, (young[0], young[span.start])),
        (slice(span.stop, len(k)), inside[-1], -math.inf, hi, (young[span.stop - 1], young[-1])),
    )
    for side, end, floor, ceiling, moduli in sides:
        branch, noise = k[side], noise_log_k[side]
        log_k = np.log(branch[branch > 0])
        margin = np.maximum(FOLD_MARGIN_SIGMAS * noise[branch > 0], FOLD_MARGIN_LOG)
        reached = np.concatenate([log_k - margin, log_k + margin, [np.log(end)]])
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


def _consistent(inside: list[dict]) -> list[dict]:
    """With every in-range feature ambiguous and no referee, the ones no other in-range feature refutes.

    A folded grip on a soft 70 mm sphere reads what its valid branch puts at twice the modulus; that
    modulus lies inside the thumb's valid ranges, where the thumb's pad would read it too, and does
    not: the grip is refuted. The thumb's own estimate lies below the grip's valid range, where a
    folded grip is what one expects: it stands. Empty when every feature is refuted."""
    return [p for p in inside if not any(_contradicts(o, p) for o in inside if o is not p)]


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
        # Clear features that another clear one refutes are left out too, unless all are: on a 65 mm,
        # 11.1 kPa sphere the thumb's tangent read 19.6 kPa, inside the secant's valid range, where the
        # secant would read it; the secant read 11.7 kPa, below the tangent's range (from 15.5 kPa),
        # where the tangent is erratic. Combined they said +21 %; the secant alone +5 %.
        unambiguous = [p for p in inside if not p["ambiguous"]]
        clear = _consistent(unambiguous) or unambiguous
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
        used = _consistent(inside) or inside or parts
        if referees:
            log_e, _ = _combine(referees)
            joined = [
                p for p in inside if p["ambiguous"] and p["valid_log_e"][0] <= log_e <= p["valid_log_e"][1]
            ]
            used = clear + joined if clear else (joined or referees)
        log_e, sigma = _combine(used)
        low, high = log_e - Z95 * sigma, log_e + Z95 * sigma
        unsettled = not referees and all(p["ambiguous"] for p in used)
        if unsettled:  # nothing says which branch: the interval takes in the other one as well
            others = [p["other_branch_pa"] for p in used if p["other_branch_pa"]]
            low = min([low, *(math.log(o[0]) for o in others)])
            high = max([high, *(math.log(o[1]) for o in others)])
        for p in parts:
            p["used"] = p in used
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
        curves = sorted((c for c in self.curves[shape] if c.feature == feature), key=lambda c: c.size_m)
        if not curves or not k > 0 or not curves[0].size_m - 1e-6 <= size_m <= curves[-1].size_m + 1e-6:
            return None
        log_k = math.log(k)
        sizes = np.array([c.size_m for c in curves])
        j = int(np.clip(np.searchsorted(sizes, size_m - 1e-9) - 1, 0, max(len(curves) - 2, 0)))
        pair = curves[j : j + 2] if len(curves) > 1 else curves * 2
        span = pair[1].size_m - pair[0].size_m
        w = 0.0 if span == 0 else float(np.clip((size_m - pair[0].size_m) / span, 0.0, 1.0))
        used = [c for c, weight in zip(pair, (1 - w, w), strict=True) if weight > 1e-9]

        def mix(f):  # noqa: ANN001
            return (1 - w) * f(pair[0]) + w * f(pair[1])

        log_e = mix(lambda c: c.log_e(log_k))
        slope = mix(lambda c: c.slope(log_k))
        rel = k_sigma / k if math.isfinite(k_sigma) else 0.0
        noise = mix(lambda c: c.noise_log_k(log_k))
        valid_log_e = tuple(mix(lambda c, i=i: math.log(c.young_range_pa[i])) for i in (0, 1))
        reach = max(0.0, valid_log_e[0] - log_e, log_e - valid_log_e[1])
        sigma_log = math.sqrt(
            mix(lambda c: c.loo_rms_log) ** 2
            + slope**2 * (noise**2 + rel**2)
            + (EXTRAPOLATION_SIGMA_PER_REACH * reach) ** 2
        )
        extrapolated = any(not (c.log_k_range[0] <= log_k <= c.log_k_range[1]) for c in used) or any(
            not (c.young_range_pa[0] <= math.exp(log_e) <= c.young_range_pa[1]) for c in used
        )
        return {
            "feature": feature,
            "stiffness_n_m": k,
            "log_e": log_e,
            "valid_log_e": valid_log_e,
            "sigma_log": max(sigma_log, 1e-6),
            "extrapolated": extrapolated,
            "ambiguous": any(c.is_folded(log_k) for c in used),
            "other_branch_pa": _union([c.other_branch_pa(log_k) for c in used]),
        }
