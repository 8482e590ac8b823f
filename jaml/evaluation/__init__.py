"""Evaluation suite (paper §2.1, eq. 5): latent–state alignment error and encoder distortion.

    from jaml import evaluation
    evaluation.alignment_error(lat_tr, st_tr, lat_te, st_te)          # [D], training-std units
    evaluation.alignment_errors(lat_tr, st_tr, {"pi_curr": (l, s), "pi_rand": (l, s)})
"""

from jaml.evaluation.alignment import (
    Regressor,
    RegressorConfig,
    alignment_error,
    alignment_errors,
    fit_regressor,
    regressor_error,
)

__all__ = [
    "Regressor",
    "RegressorConfig",
    "alignment_error",
    "alignment_errors",
    "fit_regressor",
    "regressor_error",
]
