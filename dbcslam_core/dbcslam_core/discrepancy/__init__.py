"""Model discrepancy analysis: what the nominal model gets wrong, which effect explains it.

Pure numpy; used by `dbcslam discrepancy` (dbcslam_ros.offline.discrepancy_report). One module per
part: `runs` (data, split), `effects` (vocabulary, search spaces, how an effect enters the
filter), `scoring` (the filter's log predictive likelihood as the score), `fitting`
(parameters by maximising it), `analysis` (prepare -> fit -> compare -> verdict),
`report` (the result and its contract JSON), `rollouts` (open-loop pictures, not evidence).
"""

from .analysis import DiscrepancyConfig, Resolvability, analyse, resolvability
from .effects import FILTER_EFFECTS, Hypothesis, ParamSpace, effect_size, effect_spaces
from .fitting import FitResult, fit_effect
from .report import Analysis, CandidateFit
from .rollouts import Prediction, RolloutConfig, smooth_states
from .runs import Run, default_effects, nominal_friction, split_runs
from .scoring import ModelScore, RunTrace, ScoreConfig, Scorer

__all__ = [
    "FILTER_EFFECTS",
    "Analysis",
    "CandidateFit",
    "DiscrepancyConfig",
    "FitResult",
    "Hypothesis",
    "ModelScore",
    "ParamSpace",
    "Prediction",
    "Resolvability",
    "RolloutConfig",
    "Run",
    "RunTrace",
    "ScoreConfig",
    "Scorer",
    "analyse",
    "default_effects",
    "effect_size",
    "effect_spaces",
    "fit_effect",
    "nominal_friction",
    "resolvability",
    "smooth_states",
    "split_runs",
]
