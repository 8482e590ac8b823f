"""Evaluation suite (paper §2.1, eq. 5): latent–state alignment error and encoder distortion.

    from jaml import evaluation
    evaluation.alignment_error(lat_tr, st_tr, lat_te, st_te)     # [D], training-std units
    evaluation.alignment_errors(lat_tr, st_tr, {"pi_curr": (l, s), "pi_rand": (l, s)})
    evaluation.constant_errors(st_tr, {"pi_rand": s})            # [D]: a latent with no information
    evaluation.distortion(latents, states)                       # Var ρ over random pairs
    evaluation.distortion_trimmed(latents, states)               # (exact, finite pairs', left out)
    evaluation.irregularity(latents, states, names)              # the reference's irreg_std
    evaluation.principal_axis_error(R_true, R_hat)               # Rearrange rotation blocks
    evaluation.plot_alignment(history, "alignment.png"); evaluation.plot_distortion(...)
"""

from jaml.evaluation.alignment import (
    Regressor,
    RegressorConfig,
    alignment_error,
    alignment_errors,
    constant_errors,
    fit_regressor,
    regressor_error,
    rotation_errors,
)
from jaml.evaluation.distortion import (
    distortion,
    distortion_coefficients,
    distortion_trimmed,
    irregularity,
    sample_pairs,
)
from jaml.evaluation.plots import history_records, plot_alignment, plot_distortion
from jaml.evaluation.rotation import principal_axis_error, rearrange_rotation_starts

__all__ = [
    "Regressor",
    "RegressorConfig",
    "alignment_error",
    "alignment_errors",
    "constant_errors",
    "distortion",
    "distortion_coefficients",
    "distortion_trimmed",
    "fit_regressor",
    "history_records",
    "irregularity",
    "plot_alignment",
    "plot_distortion",
    "principal_axis_error",
    "rearrange_rotation_starts",
    "regressor_error",
    "rotation_errors",
    "sample_pairs",
]
