"""`analyse`: prepare -> fit -> compare -> verdict, on the filter's own evidence.

1. prepare: split the runs (`runs.split_runs`), score the nominal model on the training
   runs (`scoring.Scorer`: the filter's summed log predictive likelihood, fixed seed:
   common random numbers across all candidates and parameters) and on the held-out runs
   with the seed and `noise_seeds` (mean and Monte-Carlo std of the held-out score).
2. fit: every candidate effect on the training runs (`fitting.fit_effect`): first the
   coarse grids of all; the `refine_best` (3) effects with the largest training gain above
   `screen` nats are then refined (golden section) and go on to the held-out test; the
   others cannot be named (this saves filter runs: a winner must also fit the training
   runs among the best; 3 keeps mass_scale / input_gain together with a third).
3. compare: each refined fit is scored on the held-out runs with the same seeds; a model's
   held-out evidence is the log-mean-exp of its seed scores (`HeldScores`: the Monte-Carlo
   estimate of the log marginal likelihood); delta_loglik = that of the extended model
   minus the nominal model's. The Monte-Carlo noise is one-sided: a mis-specified model's
   filter loses track at times and only ever scores lower (seed-to-seed std of hundreds of
   nats, against a few nats for a well-specified model). A candidate beats the nominal
   model clearly (`beats`) when its evidence exceeds the nominal model's BEST seed by
   k/2 ln(N_heldout) + min_margin (a BIC-like parameter penalty) + z x its own standard
   error, the effect is large enough to matter (`effects.effect_size` >= 1) and its
   estimate is not at a bound of its search range.
4. verdict: the clear candidate with the largest delta_loglik - penalty, or `none`; when
   the winner does not beat the second clear candidate in the same sense (by min_margin +
   z x its own standard error over the second's best seed), both are named (the data
   cannot tell them apart). mass_scale k and input_gain 1/k predict the same motion
   in this model (gravity and friction scale with the mass): when the winner is one of
   them and the other is clear too, both are always named (`EQUIVALENT`).

The open-loop rollouts (`rollouts`) from the filter's posterior means are pictures for the
report only.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from ..errors import ModelError
from ..extensions import EFFECTS
from .effects import FILTER_EFFECTS, Hypothesis, effect_size, n_free_params
from .fitting import FitResult, fit_effect
from .report import Analysis, CandidateFit
from .rollouts import Prediction, Predictor, RolloutConfig, characterise, mods_of
from .runs import Run, default_effects, split_runs
from .scoring import ModelScore, ScoreConfig, Scorer

__all__ = ["DiscrepancyConfig", "analyse"]

NOMINAL = Hypothesis()

EQUIVALENT: tuple[frozenset[str], ...] = (frozenset({"mass_scale", "input_gain"}),)
"""Effects that predict the same motion (kinematic data cannot tell them apart)."""


@dataclass(frozen=True)
class DiscrepancyConfig:
    """Analysis settings.

    particles / seed: the scoring filter (fixed seed = common random numbers);
    noise_seeds: further seeds of the held-out scores (Monte-Carlo mean and noise); z:
    margins in standard errors (module docstring); min_margin (nats): floor of the margins;
    screen (nats): training gain needed to refine an effect; refine_best: how many of the
    best effects on the training runs are refined and tested held out; effects: candidate names
    (None: `runs.default_effects` that the filter can score); holdout_fraction: held-out
    tail of a single run without held-out runs;
    horizon, stride, max_starts: the rollout pictures (`rollouts.RolloutConfig`);
    pictures: compute them; filter_overrides: `FilterConfig` fields of the scoring filter
    (`scoring.ScoreConfig.filter_overrides`).
    """

    particles: int = 300
    seed: int = 0
    noise_seeds: tuple[int, ...] = (1, 2)
    z: float = 3.0
    min_margin: float = 10.0
    screen: float = 30.0
    refine_best: int = 3
    effects: tuple[str, ...] | None = None
    holdout_fraction: float = 0.4
    horizon: int = 20
    stride: int = 2
    max_starts: int = 150
    pictures: bool = True
    filter_overrides: tuple[tuple[str, object], ...] = ()


@dataclass(frozen=True)
class _Prepared:
    train: list[Run]
    held: list[Run]
    description: str
    effects: tuple[str, ...]
    nominal_train: ModelScore
    nominal_held: ModelScore
    nom_held: HeldScores
    screen: float
    seeds: tuple[int, ...]
    refine_best: int = 3


def _effects(cfg: DiscrepancyConfig, run: Run) -> tuple[str, ...]:
    if cfg.effects is None:
        return tuple(e for e in default_effects(run.scenario) if e in FILTER_EFFECTS)
    for e in cfg.effects:
        if e not in FILTER_EFFECTS:
            known = "unknown effect" if e not in EFFECTS else "not scorable by the filter"
            msg = f"candidate effect {e!r}: {known}; valid: {sorted(FILTER_EFFECTS)}"
            raise ModelError(msg)
    return tuple(cfg.effects)


def prepare(
    runs: Sequence[Run],
    heldout_runs: Sequence[Run],
    cfg: DiscrepancyConfig,
    scorer: Scorer,
    say: Callable[[str], None],
) -> _Prepared:
    """Split, nominal scores and the measured Monte-Carlo noise (module docstring, 1)."""
    train, held, desc = split_runs(runs, heldout_runs, cfg.holdout_fraction)
    effects = _effects(cfg, train[0])
    say(f"nominal model on {len(train)} training / {len(held)} held-out run(s)")
    nom_t = scorer.score(NOMINAL, train)
    nom_h = scorer.score(NOMINAL, held)
    if not (math.isfinite(nom_t.loglik) and math.isfinite(nom_h.loglik)):
        msg = "the filter loses track of the data under the nominal model (no finite score)"
        raise ModelError(msg)
    seeds = (cfg.seed, *cfg.noise_seeds)
    hs = held_scores(NOMINAL, held, scorer, seeds)
    say(
        f"nominal evidence: training {nom_t.loglik:.1f}, held out {hs.lme:.1f} (std "
        f"{hs.std:.1f} nats over {len(seeds)} filter seeds, {cfg.particles} particles)"
    )
    return _Prepared(
        train, held, desc, effects, nom_t, nom_h, hs, cfg.screen, seeds, cfg.refine_best
    )


@dataclass(frozen=True)
class HeldScores:
    """Held-out scores of one model over the filter seeds (nats).

    lme: log-mean-exp of the seeds' scores, the Monte-Carlo estimate of the log marginal
    likelihood (the particle filter's likelihood estimate is unbiased in p, so its log is
    biased low, the more so the worse the model fits: a filter that loses track only ever
    scores lower); best: the largest seed score; std: the seeds' spread; values: all.
    """

    lme: float
    best: float
    std: float
    values: tuple[float, ...]


def held_scores(
    hyp: Hypothesis, runs: Sequence[Run], scorer: Scorer, seeds: Sequence[int]
) -> HeldScores:
    """The held-out scores of `hyp` over `seeds` (-inf when the filter loses all particles
    under every seed)."""
    vals = tuple(scorer.score(hyp, runs, s).loglik for s in seeds)
    fin = [v for v in vals if math.isfinite(v)]
    if not fin:
        return HeldScores(-math.inf, -math.inf, math.inf, vals)
    top = max(fin)
    lme = top + math.log(sum(math.exp(v - top) for v in fin) / len(vals))
    std = float(statistics.stdev(fin)) if len(fin) > 1 else 0.0
    return HeldScores(lme, top, std, vals)


def beats(a_lme: float, a_std: float, b_best: float, *, margin: float, z: float, n: int) -> bool:
    """Model A's held-out evidence exceeds model B's by more than `margin` plus z standard
    errors of A's own Monte-Carlo noise, against B's best seed (B's lower seeds may be
    track losses: one-sided noise)."""
    return a_lme - b_best > margin + z * a_std / math.sqrt(max(n, 1))


def fit_all(
    prep: _Prepared, scorer: Scorer, say: Callable[[str], None], started: float
) -> list[FitResult]:
    """Fit every candidate effect on the training runs (module docstring, 2): the coarse
    grids of all, then the refinement of the `refine_best` best above the screen."""
    nom = prep.nominal_train.loglik
    coarse = [
        fit_effect(e, prep.train, scorer, nom, prep.screen, refine=False) for e in prep.effects
    ]
    above = sorted(
        (f for f in coarse if f.train_delta >= prep.screen), key=lambda f: -f.train_delta
    )
    best = {f.effect for f in above[: prep.refine_best]}
    say(
        f"coarse grids done ({time.monotonic() - started:.0f} s); refining "
        f"{', '.join(sorted(best)) or 'nothing'}"
    )
    fits = []
    for i, c in enumerate(coarse):
        eff = c.effect
        f = fit_effect(eff, prep.train, scorer, nom, prep.screen) if eff in best else c
        fits.append(f)
        ps = ", ".join(f"{k}={v:.4g}" for k, v in f.params.items())
        say(
            f"  [{i + 1}/{len(prep.effects)}, {time.monotonic() - started:.0f} s] {eff}: "
            f"{ps}, training gain {f.train_delta:+.1f} nats"
            f"{'' if f.refined else ' (not refined)'}"
        )
    return fits


def compare(
    prep: _Prepared, fits: Sequence[FitResult], scorer: Scorer, cfg: DiscrepancyConfig
) -> list[CandidateFit]:
    """Held-out scores and the clear criteria (module docstring, 3)."""
    sc = prep.train[0].scenario
    n_h = max(prep.nominal_held.n_obs, 2)
    n_s = len(prep.seeds)
    out = []
    for f in fits:
        k = n_free_params(f.effect, sc)
        size = effect_size(f.effect, f.params, sc)
        note = ""
        if not f.refined:
            note = (
                "no training gain above the screen"
                if f.train_delta < prep.screen
                else "not among the best effects on the training runs"
            )
        elif f.at_bound:
            note = "estimate at a bound of the search range (not a plausible fit)"
        elif size < 1.0:
            note = f"effect too small to matter (size {size:.2f} < 1)"
        delta, std, rmse, nll, trk = (math.nan,) * 5
        bic = 0.5 * k * math.log(n_h)
        penalty = bic + cfg.min_margin
        hs: HeldScores | None = None
        if f.refined:
            hs = held_scores(f.hypothesis, prep.held, scorer, prep.seeds)
            s = scorer.score(f.hypothesis, prep.held)
            delta, std = hs.lme - prep.nom_held.lme, hs.std
            rmse, nll, trk = s.pred_rmse, -hs.lme / max(s.n_obs, 1), s.track_rmse
            penalty = (prep.nom_held.best - prep.nom_held.lme) + bic + cfg.min_margin
            penalty += cfg.z * std / math.sqrt(n_s)
        clear = bool(
            not note
            and hs is not None
            and beats(
                hs.lme, hs.std, prep.nom_held.best, margin=bic + cfg.min_margin, z=cfg.z, n=n_s
            )
        )
        out.append(
            CandidateFit(
                effect=f.effect,
                params=dict(f.params),
                stderr=dict(f.stderr),
                n_params=k,
                train_delta_loglik=f.train_delta,
                delta_loglik=delta,
                penalty=penalty,
                heldout_rmse=rmse,
                heldout_nll=nll,
                tracking_rmse=trk,
                clear=clear,
                size=size,
                evaluations=f.evaluations,
                note=note,
                delta_se=std / math.sqrt(n_s) if math.isfinite(std) else math.nan,
                heldout_std=std,
                heldout_lme=math.nan if hs is None else hs.lme,
                heldout_best=math.nan if hs is None else hs.best,
                heldout_seeds=() if hs is None else hs.values,
            )
        )
    return out


def _margin_key(c: CandidateFit) -> float:
    return c.delta_loglik - c.penalty if math.isfinite(c.delta_loglik) else -math.inf


def verdict(
    cands: Sequence[CandidateFit], cfg: DiscrepancyConfig, n_seeds: int
) -> tuple[CandidateFit | None, tuple[str, ...]]:
    """Winner and the ambiguous pair (module docstring, 4)."""
    clear = sorted((c for c in cands if c.clear), key=_margin_key, reverse=True)
    if not clear:
        return None, ()
    win = clear[0]
    for pair in EQUIVALENT:
        if win.effect in pair:
            other = [c for c in clear[1:] if c.effect in pair]
            if other:
                return win, (win.effect, other[0].effect)
    if len(clear) > 1:
        sec = clear[1]
        if not beats(
            win.heldout_lme,
            win.heldout_std,
            sec.heldout_best,
            margin=cfg.min_margin,
            z=cfg.z,
            n=n_seeds,
        ):
            return win, (win.effect, sec.effect)
    return win, ()


def _pictures(
    prep: _Prepared, win: CandidateFit | None, cfg: DiscrepancyConfig, scorer: Scorer
) -> tuple[Prediction | None, Prediction | None, dict[str, Any]]:
    if not cfg.pictures:
        return None, None, {}
    runs = prep.train + prep.held
    states = []
    for r in runs:
        tr = scorer.trace(NOMINAL, r)
        states.append((tr.q, tr.v))
    rcfg = RolloutConfig(horizon=cfg.horizon, stride=cfg.stride, max_starts=cfg.max_starts)
    try:
        pred = Predictor(runs, [any(r is h for h in prep.held) for r in runs], rcfg, states=states)
    except ModelError:
        return None, None, {}
    nom = pred.prediction(mods_of(()))
    ext = None if win is None else pred.prediction(mods_of((win.extension(),)))
    return nom, ext, characterise(nom, float(runs[0].scenario.dt))


def _evidence(prep: _Prepared, win: CandidateFit | None, amb: tuple[str, ...]) -> str:
    nom = prep.nominal_held
    if win is None:
        return (
            f"no candidate beats the nominal model on the held-out data by its margin "
            f"(nominal one-step prediction RMSE {nom.pred_rmse * 1e3:.2f} mm; Monte-Carlo "
            f"noise of the evidence {prep.nom_held.std:.1f} nats)."
        )
    pstr = ", ".join(
        f"{k}={v:.4g}+-{win.stderr.get(k, math.nan):.2g}" for k, v in win.params.items()
    )
    text = (
        f"the nominal model explains the held-out observations {win.delta_loglik:.0f} nats "
        f"worse than with {win.effect} ({pstr}; needed > {win.penalty:.0f}); one-step "
        f"prediction RMSE {nom.pred_rmse * 1e3:.2f} -> {win.heldout_rmse * 1e3:.2f} mm."
    )
    if amb:
        text += (
            f" The data cannot tell {amb[0]} from {amb[1]} apart (held-out evidence within "
            "the margin): both named."
        )
    return text


def analyse(
    runs: Sequence[Run],
    heldout_runs: Sequence[Run] = (),
    cfg: DiscrepancyConfig | None = None,
    *,
    progress: Callable[[str], None] | None = None,
) -> Analysis:
    """Fit every candidate effect on the training data, compare on the held-out data."""
    cfg = cfg or DiscrepancyConfig()
    say = progress or (lambda s: None)
    started = time.monotonic()
    scorer = Scorer(
        ScoreConfig(particles=cfg.particles, seed=cfg.seed, filter_overrides=cfg.filter_overrides),
        say,
    )
    prep = prepare(runs, heldout_runs, cfg, scorer, say)
    fits = fit_all(prep, scorer, say, started)
    cands = compare(prep, fits, scorer, cfg)
    win, amb = verdict(cands, cfg, len(prep.seeds))
    extended = (
        None if win is None else scorer.score(Hypothesis.make(win.effect, win.params), prep.held)
    )
    nom_pred, ext_pred, resid = _pictures(prep, win, cfg, scorer)
    name = "none" if win is None else (" or ".join(amb) if amb else win.effect)
    cands.sort(key=_margin_key, reverse=True)
    elapsed = time.monotonic() - started
    say(f"verdict: {name} ({scorer.evaluations} filter runs, {elapsed:.0f} s)")
    return Analysis(
        verdict=name,
        evidence=_evidence(prep, win, amb),
        nominal=prep.nominal_held,
        nominal_train=prep.nominal_train,
        extended=extended,
        winner=win,
        ambiguous=amb,
        candidates=tuple(cands),
        residuals=resid,
        heldout_description=prep.description,
        nominal_prediction=nom_pred,
        extended_prediction=ext_pred,
        settings={
            "score": "filter log predictive likelihood, summed over the observations",
            "particles": cfg.particles,
            "seed": cfg.seed,
            "noise_seeds": list(cfg.noise_seeds),
            "z": cfg.z,
            "min_margin_nats": cfg.min_margin,
            "screen_nats": prep.screen,
            "rollout_horizon_steps": cfg.horizon,
        },
        mc_noise=prep.nom_held.std,
        filter_runs=scorer.evaluations,
        seconds=elapsed,
    )
