"""Fitting an effect's parameters by maximising the filter's evidence on the training runs.

One parameter (`fit_1d_steps`): the coarse grid of its `ParamSpace` walked outwards from
the start value, both sides in step (one point per side and round); a side stops after two
points in a row that do not score above the best so far on that side (unless the space is
marked not unimodal, `ParamSpace.unimodal`: then the whole grid; the score is taken as
unimodal along one parameter at this resolution, up to single points where the filter lost
track: the score of a mis-specified model is rough, e.g. with a hidden 75 ms sensor delay
the training score was +3016 nats nominal, -2334 at 20 ms, +3271 at 50 ms, +6142 at 90 ms;
a parameter the data do not resolve, e.g. a sensor bias along the edge, leaves the score
unchanged; when the first point on each side scores as the start value to `NO_EFFECT`
nats, i.e. to rounding, the parameter does not reach the filter on these data, e.g.
input_gain with zero inputs or a sensor bias along the gripper's jaws, and the walk stops
there). When the best
grid point beats the starting value by less than the screening
margin the effect is not refined (it cannot be named anyway: `analysis`). Otherwise, when
the best grid point is the last one evaluated on its side, the bound of the range is
evaluated too (an optimum at the bound is flagged, `FitResult.at_bound`, never named); then
the peak is refined by successive parabolic interpolation in the search coordinate (log for
factors) through the best point and its evaluated neighbours, safeguarded: the new point
stays strictly inside the bracket, and a golden-section point of the larger side is used
where the parabola is not concave (with the best point at the bound: the golden-section
point towards its neighbour, once, stopping when it scores lower); it stops when the step
is below 0.5 % of the range or after `refine_steps` points. The best evaluated point wins.
Uncertainty: from the curvature c (nats per unit^2) of the parabola through the best point
and its nearest evaluated neighbours, stderr = 1 / sqrt(-2 c) (Laplace approximation; inf
when not concave). Several parameters (sensor_bias): coordinate steps, one 1-D fit per
coordinate with the others at their current values (y, x[, yaw]). A pose bias (y, x, yaw)
is swept twice: first on the coarse grids only, then again from those values with the
refinement (a coordinate the first sweep moved is refined around its value whatever its
further gain; one it left at 0 must pass the screen again). y and yaw act jointly: a
rotated reading of the triangle between the gripper's jaws moves its lowest vertex, which a
y shift partly undoes, and with the yaw bias unremoved the filter loses track at most y
points. Measured on benchmark gripper draw 3 (hidden y 3.3 mm, yaw 0.040 rad; training run,
150 particles; nominal -8529 nats): at yaw 0 the y grid scored -13411 / 698 / -8570 /
-5719 / -9162 / +4328 at y = -7 / -4 / -2 / +2 / +4 / +7 mm, so one sweep fitted y 7 mm and
then yaw 0.056 (wrong); at yaw 0.05 the y grid peaks at 4 mm (+5657; the truth +5708), which
the second sweep finds.

The fits are generators (`FitSteps`): they yield the batch of hypotheses they need scored
next and receive the scores. `drive` runs one to its end; `drive_all` runs several in
step, one batch of all their pending hypotheses per round, so that a scorer with a worker
pool (`Scorer.prefetch`) evaluates the filter runs of a round in parallel. The result does
not depend on how the batches are evaluated.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

from .effects import Hypothesis, ParamSpace, effect_spaces
from .runs import Run
from .scoring import Scorer

__all__ = [
    "FitResult",
    "FitSteps",
    "drive",
    "drive_all",
    "fit_1d",
    "fit_1d_steps",
    "fit_effect",
    "fit_effect_steps",
]

T = TypeVar("T")

NO_EFFECT = 1e-3
"""nats: score changes up to this are rounding (a parameter without effect on the data)."""
FitSteps = Generator[list[Hypothesis], list[float], T]
"""A fit as a generator: yields hypotheses to score, receives their scores, returns T."""

ScoreBatch = Callable[[list[Hypothesis]], list[float]]


@dataclass(frozen=True)
class FitResult:
    """Fitted parameters of one effect on the training runs.

    evaluations: distinct hypotheses the fit scored (filter runs on the training runs,
    whether or not a cache already held them); best_seen: the highest-scoring hypothesis the
    fit scored and its score (nats; also when it stayed below the screen and the fit kept
    the nominal parameters), None before any was scored."""

    effect: str
    params: dict[str, float]
    stderr: dict[str, float]
    train_loglik: float
    train_delta: float  # nats over the nominal model
    at_bound: bool
    refined: bool
    evaluations: int
    points: tuple[tuple[float, ...], ...] = field(default=(), repr=False)
    best_seen: tuple[Hypothesis, float] | None = None

    @property
    def hypothesis(self) -> Hypothesis:
        return Hypothesis.make(self.effect, self.params)

    @property
    def best_seen_delta(self) -> float:
        """Training gain (nats over the nominal model) of `best_seen` (-inf without one)."""
        if self.best_seen is None:
            return -math.inf
        return self.best_seen[1] - (self.train_loglik - self.train_delta)


@dataclass(frozen=True)
class _OneD:
    x: float
    stderr: float
    ll: float
    at_bound: bool
    refined: bool
    points: tuple[tuple[float, float], ...]


def drive(steps: FitSteps[T], score: ScoreBatch) -> T:
    """Run one fit generator to its end, scoring its batches with `score`."""
    return drive_all([steps], score)[0]


def drive_all(all_steps: Sequence[FitSteps[T]], score: ScoreBatch) -> list[T]:
    """Run fit generators in step: each round scores the pending batches of all of them
    as one batch (module docstring)."""
    results: dict[int, T] = {}
    pending: dict[int, list[Hypothesis]] = {}

    def advance(i: int, sent: list[float] | None) -> None:
        try:
            pending[i] = next(all_steps[i]) if sent is None else all_steps[i].send(sent)
        except StopIteration as stop:
            results[i] = stop.value
            pending.pop(i, None)

    for i in range(len(all_steps)):
        advance(i, None)
    while pending:
        order = sorted(pending)
        flat = [h for i in order for h in pending[i]]
        vals = score(flat)
        pos = 0
        for i in order:
            n = len(pending[i])
            advance(i, vals[pos : pos + n])
            pos += n
    return [results[i] for i in range(len(all_steps))]


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


def _next_point(pts: dict[float, float], u0: float) -> float | None:
    """The next refinement point around the best u0 (module docstring): with u0 at the end
    of the evaluated points, the golden-section point towards its neighbour (None without
    one)."""
    us = sorted(pts)
    i = us.index(u0)
    g = (3.0 - math.sqrt(5.0)) / 2.0
    if len(us) < 2:
        return None
    if i == 0 or i == len(us) - 1:
        nb = us[1] if i == 0 else us[-2]
        return u0 + g * (nb - u0)
    a, b = us[i - 1], us[i + 1]
    la, l0, lb = pts[a], pts[u0], pts[b]
    num = (u0 - a) ** 2 * (l0 - lb) - (u0 - b) ** 2 * (l0 - la)
    den = (u0 - a) * (l0 - lb) - (u0 - b) * (l0 - la)
    golden = u0 + g * (b - u0) if b - u0 > u0 - a else u0 - g * (u0 - a)
    # u0 is the best of the three: the parabola is concave unless den <= 0 (ties, -inf)
    if not (math.isfinite(la) and math.isfinite(lb) and den > 0.0):
        return golden
    v = u0 - 0.5 * num / den
    inner = 0.02 * (b - a)
    return min(max(v, a + inner), b - inner)


def fit_1d_steps(
    make: Callable[[float], Hypothesis],
    sp: ParamSpace,
    base: tuple[float, float],
    screen: float,
    *,
    refine_steps: int = 3,
    refine: bool = True,
) -> FitSteps[_OneD]:
    """Maximise the score of make(x) over x in sp (module docstring); base = (x0, score at
    x0). A generator: yields hypotheses, receives their scores."""
    u_base = sp.to_u(base[0])
    pts: dict[float, float] = {u_base: base[1]}
    sides = [
        sorted((x for x in sp.grid if sp.to_u(x) < u_base), reverse=True),
        sorted(x for x in sp.grid if sp.to_u(x) > u_base),
    ]
    nxt, top, misses = [0, 0], [base[1], base[1]], [0, 0]
    first = True
    while True:  # the grid outwards, both sides in step
        batch = [(s, sides[s][nxt[s]]) for s in (0, 1) if nxt[s] < len(sides[s])]
        if not batch:
            break
        vals = yield [make(x) for _, x in batch]
        for (s, x), val in zip(batch, vals, strict=True):
            pts[sp.to_u(x)] = val
            misses[s] = 0 if val > top[s] else misses[s] + 1
            top[s] = max(top[s], val)
            nxt[s] = nxt[s] + 1 if misses[s] < 2 or not sp.unimodal else len(sides[s])
        if first and all(abs(v - base[1]) <= NO_EFFECT for v in vals):
            break  # the parameter does not reach the score on these data (module docstring)
        first = False

    def best() -> tuple[float, float]:
        u = max(pts, key=lambda k: pts[k])
        return u, pts[u]

    u0, l0 = best()
    if l0 - base[1] < screen:
        return _OneD(base[0], math.inf, base[1], False, False, _points(sp, pts))
    if not refine:  # coarse stage only (`analysis.fit_all` refines the best effects)
        x0 = sp.from_u(u0)
        return _OneD(x0, math.inf, l0, sp.at_bound(x0), False, _points(sp, pts))
    us = sorted(pts)
    ends = [(us[0], sp.lo), (us[-1], sp.hi)]
    bound = [x for u, x in ends if u0 == u and x != base[0] and sp.to_u(x) not in pts]
    if bound:  # best at the end of what was evaluated: the bound of the range too
        (val,) = yield [make(bound[0])]
        pts[sp.to_u(bound[0])] = val
    tol = 0.005 * (sp.to_u(sp.hi) - sp.to_u(sp.lo))
    for _ in range(refine_steps):
        u0, l0 = best()
        us = sorted(pts)
        at_end = u0 in (us[0], us[-1])
        v = _next_point(pts, u0)
        if v is None or abs(v - u0) < tol or v in pts:
            break
        (val,) = yield [make(sp.from_u(v))]
        pts[v] = val
        if at_end and val <= l0:  # rising towards the bound: the optimum is at the bound
            break
    u_best, l_best = best()
    x = sp.from_u(u_best)
    curv = _curvature(pts, u_best)
    se_u = 1.0 / math.sqrt(-2.0 * curv) if math.isfinite(curv) and curv < 0 else math.inf
    se = se_u * x if sp.log else se_u
    return _OneD(x, se, l_best, sp.at_bound(x), True, _points(sp, pts))


def fit_1d(
    make: Callable[[float], Hypothesis],
    sp: ParamSpace,
    score: Callable[[Hypothesis], float],
    base: tuple[float, float],
    screen: float,
    *,
    refine_steps: int = 3,
    refine: bool = True,
) -> _OneD:
    """`fit_1d_steps` with a scoring function of one hypothesis."""
    steps = fit_1d_steps(make, sp, base, screen, refine_steps=refine_steps, refine=refine)
    return drive(steps, lambda hs: [score(h) for h in hs])


def _points(sp: ParamSpace, pts: dict[float, float]) -> tuple[tuple[float, float], ...]:
    return tuple((sp.from_u(u), pts[u]) for u in sorted(pts))


def fit_effect_steps(
    effect: str,
    runs: Sequence[Run],
    nominal_loglik: float,
    screen: float,
    *,
    refine: bool = True,
) -> FitSteps[FitResult]:
    """Fit `effect` on `runs` (module docstring) as a generator of hypotheses to score on
    `runs`; nominal_loglik: the nominal score there."""
    sc = runs[0].scenario
    spaces = effect_spaces(sc, effect)
    cur = {s.name: s.default for s in spaces}
    ll = nominal_loglik
    stderr: dict[str, float] = {s.name: math.inf for s in spaces}
    at_bound = False
    refined = False
    points: list[tuple[float, ...]] = []
    seen: set[Hypothesis] = set()
    best_seen: tuple[Hypothesis, float] | None = None
    # (space, refine, screen) per coordinate step (module docstring: a pose bias is swept
    # twice, the first sweep on the grid only)
    plan: list[tuple[ParamSpace, bool, float | None]]
    if effect == "sensor_bias" and any(sp.name == "yaw" for sp in spaces):
        plan = [(sp, False, screen) for sp in spaces] + [(sp, refine, None) for sp in spaces]
    else:
        plan = [(sp, refine, screen) for sp in spaces]
    for sp, ref, scr in plan:

        def make(x: float, name: str = sp.name) -> Hypothesis:
            return Hypothesis.make(effect, {**cur, name: x})

        # second sweep: a coordinate the first moved is refined around its value (no
        # screen: its gain over the nominal model was screened in the first sweep)
        gate = (0.0 if cur[sp.name] != sp.default else screen) if scr is None else scr
        steps = fit_1d_steps(make, sp, (cur[sp.name], ll), gate, refine=ref)
        try:
            batch = next(steps)
            while True:
                seen.update(batch)
                vals = yield batch
                for h, v in zip(batch, vals, strict=True):
                    if math.isfinite(v) and (best_seen is None or v > best_seen[1]):
                        best_seen = (h, v)
                batch = steps.send(vals)
        except StopIteration as stop:
            res: _OneD = stop.value
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
        evaluations=len(seen),
        points=tuple(points),
        best_seen=best_seen,
    )


def batch_scorer(scorer: Scorer, runs: Sequence[Run]) -> ScoreBatch:
    """Scores of a batch of hypotheses on `runs` (their filter runs prefetched as one batch:
    in parallel with a worker pool)."""

    def score(hs: list[Hypothesis]) -> list[float]:
        scorer.prefetch((h, runs, None) for h in hs)
        return [scorer.score(h, runs).loglik for h in hs]

    return score


def fit_effect(
    effect: str,
    runs: Sequence[Run],
    scorer: Scorer,
    nominal_loglik: float,
    screen: float,
    *,
    refine: bool = True,
) -> FitResult:
    """Fit `effect` on `runs` with `scorer` (module docstring)."""
    steps = fit_effect_steps(effect, runs, nominal_loglik, screen, refine=refine)
    return drive(steps, batch_scorer(scorer, runs))
