"""The analysis result: candidate fits, verdict and the contract JSON (`Analysis.to_dict`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..extensions import ModelExtension
from .rollouts import Prediction
from .scoring import ModelScore

__all__ = ["Analysis", "CandidateFit"]


def _r(x: float, nd: int = 6) -> float | None:
    return round(x, nd) if math.isfinite(x) else None


@dataclass(frozen=True)
class CandidateFit:
    """One effect fitted on the training runs and scored on the held-out runs.

    train_delta_loglik / delta_loglik: evidence gain over the nominal model (nats) on the
    training / held-out runs (nan: not scored held out, see note); penalty: what the held-out
    gain must exceed (parameter penalty + Monte-Carlo margin); heldout_rmse: one-step
    position prediction RMSE (m); clear: beats the nominal model by the margin and is a
    valid fit (no note).
    """

    effect: str
    params: dict[str, float]
    stderr: dict[str, float]
    n_params: int
    train_delta_loglik: float
    delta_loglik: float
    penalty: float
    heldout_rmse: float
    heldout_nll: float
    tracking_rmse: float
    clear: bool
    size: float
    evaluations: int
    note: str = ""
    delta_se: float = math.nan
    heldout_std: float = math.nan  # seed-to-seed std of its own held-out score (nats)
    heldout_lme: float = math.nan  # held-out evidence: log-mean-exp over the seeds (nats)
    heldout_best: float = math.nan  # its best seed (nats)
    heldout_seeds: tuple[float, ...] = ()

    def extension(self) -> ModelExtension:
        return ModelExtension.make(self.effect, **self.params)

    def to_dict(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "params": {k: round(v, 6) for k, v in self.params.items()},
            "stderr": {k: _r(v) for k, v in self.stderr.items()},
            "delta_loglik": _r(self.delta_loglik, 3),
            "delta_loglik_se": _r(self.delta_se, 3),
            "heldout_loglik_seeds": [_r(v, 2) for v in self.heldout_seeds],
            "train_delta_loglik": _r(self.train_delta_loglik, 3),
            "penalty": _r(self.penalty, 3),
            "heldout_rmse": _r(self.heldout_rmse),
            "heldout_nll": _r(self.heldout_nll, 4),
            "tracking_rmse": _r(self.tracking_rmse),
            "clear": self.clear,
            "size": _r(self.size, 3),
            "filter_runs": self.evaluations,
            "note": self.note,
        }


@dataclass(frozen=True)
class Analysis:
    """Result of `analyse`. `to_dict()` is the contract JSON.

    nominal / extended: held-out scores (`ModelScore`); nominal_train: the nominal score on
    the training runs; mc_noise: measured std (nats) of the held-out score across filter
    seeds (nan when no candidate reached the held-out test: then it is not measured);
    filter_runs / seconds / cpu_seconds: filter runs made, wall time, their summed CPU time
    (across the worker processes); nominal_prediction / extended_prediction: open-loop
    rollout pictures.
    """

    verdict: str
    evidence: str
    nominal: ModelScore
    nominal_train: ModelScore
    extended: ModelScore | None
    winner: CandidateFit | None
    ambiguous: tuple[str, ...]
    candidates: tuple[CandidateFit, ...]
    residuals: dict[str, Any]
    heldout_description: str
    nominal_prediction: Prediction | None
    extended_prediction: Prediction | None
    settings: dict[str, Any]
    mc_noise: float
    filter_runs: int
    seconds: float
    cpu_seconds: float = math.nan  # summed CPU time of the filter runs (all processes)

    @property
    def gain(self) -> float:
        """Nominal / extended held-out one-step prediction RMSE (1 without a winner)."""
        if self.extended is None or not self.extended.pred_rmse > 0.0:
            return 1.0
        return float(self.nominal.pred_rmse / self.extended.pred_rmse)

    @property
    def loglik_gain(self) -> float:
        """Held-out evidence of the extended over the nominal model (nats, mean over the
        filter seeds; 0 without a winner)."""
        return 0.0 if self.winner is None else self.winner.delta_loglik

    @property
    def tracking_gain(self) -> float:
        """Nominal / extended held-out tracking RMSE (posterior mean vs observation)."""
        if self.extended is None or not self.extended.track_rmse > 0.0:
            return 1.0
        return float(self.nominal.track_rmse / self.extended.track_rmse)

    def model_extensions(self) -> tuple[ModelExtension, ...]:
        return () if self.winner is None else (self.winner.extension(),)

    def to_dict(self) -> dict[str, Any]:
        ext = self.extended if self.extended is not None else self.nominal
        w = self.winner
        n = max(self.nominal.n_obs, 1)
        return {
            "verdict": self.verdict,
            "evidence": self.evidence,
            "nominal": {
                "heldout_rmse": _r(self.nominal.pred_rmse),
                "heldout_nll": _r(-self.nominal.loglik / n, 4),
                "heldout_loglik": _r(self.nominal.loglik, 3),
                "tracking_rmse": _r(self.nominal.track_rmse),
                "train_loglik": _r(self.nominal_train.loglik, 3),
            },
            "extended": {
                "effect": "none" if w is None else w.effect,
                "params": {} if w is None else {k: round(v, 6) for k, v in w.params.items()},
                "stderr": {} if w is None else {k: _r(v) for k, v in w.stderr.items()},
                "heldout_rmse": _r(ext.pred_rmse),
                "heldout_nll": _r(-ext.loglik / max(ext.n_obs, 1), 4),
                "heldout_loglik": _r(ext.loglik, 3),
                "tracking_rmse": _r(ext.track_rmse),
            },
            "gain": round(self.gain, 4),
            "loglik_gain": round(self.loglik_gain, 3),
            "tracking_gain": round(self.tracking_gain, 4),
            "ambiguous": list(self.ambiguous),
            "candidates": [c.to_dict() for c in self.candidates],
            "heldout": self.heldout_description,
            "mc_noise_nats": _r(self.mc_noise, 3),
            "filter_runs": self.filter_runs,
            "seconds": round(self.seconds, 1),
            "filter_cpu_seconds": _r(self.cpu_seconds, 1),
            "residuals": self.residuals,
            "settings": self.settings,
        }
