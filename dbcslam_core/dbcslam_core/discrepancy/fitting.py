"""Fitting an effect's parameters by maximising the filter's evidence on the training runs.

One parameter (`fit_1d`): the coarse grid of its `ParamSpace` (plus the nominal value),
walked outwards from the start value on each side until two points in a row score below
the start value (the score is taken as unimodal along one parameter at this resolution,
up to single points where the filter lost track); when the
best grid point beats the starting value by less than the screening margin the effect is
not refined (it cannot be named anyway: `analysis`). Otherwise the bracket
between the best grid point's neighbours is refined by golden-section search (in the search
coordinate: log for factors; robust to the rough score of badly mis-specified models, where
the filter loses track); the best evaluated point wins. When the best grid point is the
last of the grid the bound of the range is evaluated too; an optimum at the bound is
flagged (`FitResult.at_bound`, never named). Uncertainty: from the curvature c (nats per
unit^2) of the parabola through the best point and its evaluated neighbours,
stderr = 1 / sqrt(-2 c) (Laplace approximation; inf when not concave). Several parameters
(sensor_bias): coordinate steps, one `fit_1d` per coordinate with the others at their
current values (y, x[, yaw]).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from .effects import Hypothesis, ParamSpace, effect_spaces
from .runs import Run
from .scoring import Scorer

__all__ = ["FitResult", "fit_1d", "fit_effect"]


@dataclass(frozen=True)
class FitResult:
    """Fitted parameters of one effect on the training runs."""

    effect: str
    params: dict[str, float]
    stderr: dict[str, float]
    train_loglik: float
    train_delta: float  # nats over the nominal model
    at_bound: bool
    refined: bool
    evaluations: int
    points: tuple[tuple[float, ...], ...] = field(default=(), repr=False)

    @property
    def hypothesis(self) -> Hypothesis:
        return Hypothesis.make(self.effect, self.params)


@dataclass(frozen=True)
class _OneD:
    x: float
    stderr: float
    ll: float
    at_bound: bool
    refined: bool
    points: tuple[tuple[float, float], ...]


def _curvature(pts: dict[float, float], u0: float) -> float:
    """Curvature c (nats per unit^2) of the parabola through the best point u0 and its
    nearest evaluated neighbours on both sides (nan at the end of the evaluated range)."""
    us = sorted(pts)
    i = us.index(u0)
    if i == 0 or i == len(us) - 1:
        return math.nan
    a, b, c = us[i - 1], u0, us[i + 1]
    la, lb, lc = pts[a], pts[b], pts[c]
    return float(((lc - lb) / (c - b) - (lb - la) / (b - a)) / (c - a))


def fit_1d(
    make: Callable[[float], Hypothesis],
    sp: ParamSpace,
    score: Callable[[Hypothesis], float],
    base: tuple[float, float],
    screen: float,
    *,
    golden_steps: int = 4,
    refine: bool = True,
) -> _OneD:
    """Maximise score(make(x)) over x in sp (module docstring). base = (x0, score at x0)."""
    pts: dict[float, float] = {sp.to_u(base[0]): base[1]}
    # the grid outwards from the start value on each side; a side stops after two points in
    # a row that score below the start value (one alone may be a point where the filter
    # lost track: the score of a mis-specified model is rough)
    u_base = sp.to_u(base[0])
    lower = sorted((x for x in sp.grid if sp.to_u(x) < u_base), reverse=True)
    upper = sorted(x for x in sp.grid if sp.to_u(x) > u_base)
    for side in (lower, upper):
        below = 0
        for x in side:
            val = score(make(x))
            pts[sp.to_u(x)] = val
            below = below + 1 if val < base[1] else 0
            if below == 2:
                break

    def best() -> tuple[float, float]:
        u = max(pts, key=lambda k: pts[k])
        return u, pts[u]

    def ev(u: float) -> float:
        if u not in pts:
            pts[u] = score(make(sp.from_u(u)))
        return pts[u]

    u0, l0 = best()
    if l0 - base[1] < screen:
        return _OneD(base[0], math.inf, base[1], False, False, _points(sp, pts))
    if not refine:  # coarse stage only (`analysis.fit_all` refines the best effects)
        x0 = sp.from_u(u0)
        return _OneD(x0, math.inf, l0, sp.at_bound(x0), False, _points(sp, pts))
    grid_u = sorted(pts)
    if u0 == grid_u[0] and sp.lo != base[0]:  # best at the end of the grid: the bound too
        ev(sp.to_u(sp.lo))
    if u0 == grid_u[-1] and sp.hi != base[0]:
        ev(sp.to_u(sp.hi))
    u0, _ = best()
    grid_u = sorted(pts)
    i = grid_u.index(u0)
    a, b = grid_u[max(i - 1, 0)], grid_u[min(i + 1, len(grid_u) - 1)]
    # golden-section search of the bracket [a, b] around the best grid point
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = b - g * (b - a), a + g * (b - a)
    for _ in range(golden_steps):
        if not b - a > 1e-9:
            break
        if ev(c) >= ev(d):
            b, d = d, c
            c = b - g * (b - a)
        else:
            a, c = c, d
            d = a + g * (b - a)
    u_best, l_best = best()
    x = sp.from_u(u_best)
    curv = _curvature(pts, u_best)
    se_u = 1.0 / math.sqrt(-2.0 * curv) if math.isfinite(curv) and curv < 0 else math.inf
    se = se_u * x if sp.log else se_u
    return _OneD(x, se, l_best, sp.at_bound(x), True, _points(sp, pts))


def _points(sp: ParamSpace, pts: dict[float, float]) -> tuple[tuple[float, float], ...]:
    return tuple((sp.from_u(u), pts[u]) for u in sorted(pts))


def fit_effect(
    effect: str,
    runs: Sequence[Run],
    scorer: Scorer,
    nominal_loglik: float,
    screen: float,
    *,
    refine: bool = True,
) -> FitResult:
    """Fit `effect` on `runs` (module docstring); nominal_loglik: the nominal score there."""
    sc = runs[0].scenario
    spaces = effect_spaces(sc, effect)
    cur = {s.name: s.default for s in spaces}
    ll = nominal_loglik
    before = scorer.evaluations
    stderr: dict[str, float] = {s.name: math.inf for s in spaces}
    at_bound = False
    refined = False
    points: list[tuple[float, ...]] = []

    def score(h: Hypothesis) -> float:
        return scorer.score(h, runs).loglik

    for sp in spaces:

        def make(x: float, name: str = sp.name) -> Hypothesis:
            return Hypothesis.make(effect, {**cur, name: x})

        res = fit_1d(make, sp, score, (cur[sp.name], ll), screen, refine=refine)
        cur[sp.name] = res.x
        stderr[sp.name] = res.stderr
        ll = res.ll
        at_bound = at_bound or res.at_bound
        refined = refined or res.refined
        points += [(x, l_) for x, l_ in res.points]
    if sc.nq == 2 and effect == "sensor_bias":
        cur["yaw"] = 0.0
        stderr["yaw"] = 0.0
    return FitResult(
        effect=effect,
        params=cur,
        stderr=stderr,
        train_loglik=ll,
        train_delta=ll - nominal_loglik,
        at_bound=at_bound,
        refined=refined,
        evaluations=scorer.evaluations - before,
        points=tuple(points),
    )
