"""Tracking parameters (direct SE(3) alignment). Values from ALGORITHM_NOTES.md, made fields."""
from __future__ import annotations

from dataclasses import dataclass

from ..config_fields import param


@dataclass(frozen=True)
class TrackingConfig:
    """Direct image alignment against the semi-dense map."""
    sigma_i: float = param(4.0, "intensity noise std in grey levels (weight 1/(sigma_i^2 + ...))", 0.01, 100.0)
    huber: float = param(1.5, "Huber threshold on the normalised residual", 0.01, 100.0)
    max_iter_finest: int = param(20, "LM iteration cap on the finest tracking level", 1, 1000)
    max_iter_coarse: int = param(50, "LM iteration cap on the level above the finest", 1, 1000)
    max_iter_coarsest: int = param(100, "LM iteration cap on the coarser levels", 1, 1000)
    converge_ratio: float = param(0.999, "stop a level when err/last_err exceeds this after an accepted step", 0.5, 1.0)
    converge_eps: float = param(1e-8, "stop a level when |dxi|^2 falls below this", 0.0, 1.0)
    lm_lambda_init: float = param(0.2, "LM damping after the first rejected step", 0.0, 100.0)
    good_residual_const: float = param(40.0, "good-residual test: r^2 / (c^2 + g^2 |grad|^2) < 1; this is c", 0.0, 1000.0)
    good_residual_grad: float = param(0.5, "good-residual test gradient factor g", 0.0, 10.0)
    min_good_ratio: float = param(0.5, "lost when good/(good+bad) falls below this", 0.0, 1.0)
    min_inside_ratio: float = param(0.01, "lost when fewer than this share of the level's pixels warp into the image", 0.0, 1.0)
    affine_brightness: bool = param(False, "estimate an affine brightness change a*I+b per frame")
    affine_huber: float = param(5.0, "robust threshold (grey levels) for the brightness estimate", 0.1, 255.0)
    constant_velocity: bool = param(False, "initial guess from constant velocity instead of the last pose")
