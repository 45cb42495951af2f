"""Tracking parameters (direct SE(3) alignment). Values from ALGORITHM_NOTES.md, made fields."""
from __future__ import annotations

from dataclasses import dataclass

from ..config_fields import param


@dataclass(frozen=True)
class TrackingConfig:
    """Direct image alignment against the semi-dense map."""
    sigma_i: float = param(2.0, "intensity noise std in grey levels (weight 1/(sigma_i^2 + ...)); LSD-SLAM used 4, "
                           "2 measured better on ICL and the synthetic hand-held sequence", 0.01, 100.0)
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
    max_abs_residual: float = param(15.0, "lost when the finest level's residuals spread more than this: mean "
                                    "|r - median(r)| in grey levels (a common brightness offset does not count; 0 = off)",
                                    0.0, 255.0)
    min_inside_ratio: float = param(0.01, "lost when fewer than this share of the level's pixels warp into the image", 0.0, 1.0)
    affine_brightness: bool = param(True, "estimate the affine brightness change I_new = a*I_ref + b (a = exp(alpha)) "
                                    "jointly with the pose (8 unknowns; auto-exposure cameras; off: brightness "
                                    "taken as constant)")
    max_gain_change: float = param(2.0, "lost when the estimated gain a (new frame relative to the reference) is above "
                                   "this or below its inverse (a flat garbage image can be 'explained' by a -> 0)",
                                   1.0, 100.0)
    saturation: float = param(250.0, "skip points whose reference or new (smoothed) intensity is at or above this: "
                              "clipped pixels break the brightness model (256 = off; raise it for photometrically "
                              "corrected images, which exceed 255)", 0.0, 1e6)
    affine_prior_a: float = param(1e-2, "weak prior on alpha = log a towards 0: energy per used point prior*alpha^2", 0.0, 1e12)
    affine_prior_b: float = param(1e-5, "weak prior on the offset b towards 0: energy per used point prior*b^2 "
                                  "(b in grey levels)", 0.0, 1e12)
    depth_image_min_grad: float = param(5.0, "depth-image tracking: use pixels whose 3x3 max gradient is at least this (0 = all)",
                                        0.0, 255.0)
    depth_image_max_step: float = param(0.08, "depth-image tracking: drop pixels whose neighbourhood depth range exceeds "
                                        "this fraction of their depth (occlusion boundaries; 0 = keep)", 0.0, 10.0)
    depth_image_edge_window: int = param(9, "depth-image tracking: neighbourhood size (px) of the depth-step test", 1, 31)
    constant_velocity: bool = param(False, "initial guess from constant velocity instead of the last pose")
    lm_lambda_accept_max: float = param(0.2, "after an accepted step lambda becomes 0 if it was at most this", 0.0, 100.0)
    lm_lambda_accept_factor: float = param(0.5, "after an accepted step a larger lambda is multiplied by this", 0.0, 1.0)
    lm_lambda_reject_factor: float = param(2.0, "after a rejected step a non-zero lambda is multiplied by this to the power of the try "
                                      "within the iteration (LSD-SLAM)", 1.0, 100.0)
    smooth_sigma: float = param(0.7, "Gaussian blur (std, px of each level) of reference and new tracking images "
                                "before sampling: band-limits them so sub-pixel interpolation is accurate (0 = off)",
                                0.0, 5.0)
    interpolation: str = param("bspline", "sampling of the new image on the finest tracking level: bilinear (4 taps, "
                               "interpolated central-difference gradients) or bspline (cubic B-spline, 16 taps, "
                               "exact gradient, far less pixel locking)", choices=("bilinear", "bspline"))
    interpolation_coarse: str = param("bilinear", "sampling on the coarser levels (bilinear: smoother, wider basin)",
                                      choices=("bilinear", "bspline"))
    point_stride: int = param(1, "on the finest tracking level use only the map points with (x + y) % point_stride == 0 "
                              "(2: a checkerboard, half the points and about half that level's cost; the next coarser "
                              "level: coarse_point_stride, the others keep all their points)", 1, 8)
    coarse_point_stride: int = param(1, "the same thinning on the level above the finest tracking level (2: a "
                                     "checkerboard); that level only brings the pose into the finest level's basin",
                                     1, 8)
    border_px: float = param(1.0, "a warped point is used only this far (px) inside the image border", 0.0, 20.0)
    min_warp_depth: float = param(1e-3, "skip points whose warped depth is at or below this (map units)", 0.0, 10.0)
    min_points: int = param(10, "a level with fewer usable points than this is skipped (finest: lost)", 6, 100000)
    coarsest_level: int = param(4, "coarsest pyramid level used for tracking (capped by the pyramid)", 0, 10)
    min_hessian_diag: float = param(1e-2, "treat the system as singular when max diag(H) per used point is below this "
                                    "(textureless image: no update)", 0.0, 1e6)
    solve_eps: float = param(1e-12, "Cholesky pivot threshold relative to the largest diagonal (singular system)", 0.0, 1.0)
    noise_sigma_gain: float = param(1.0, "tracking weights use sigma = max(sigma_i, this * the frame's residual noise "
                                    "estimate) (0 = constant sigma_i)", 0.0, 10.0)
    noise_smoothing: float = param(0.2, "weight of the newest frame in the exponential smoothing of the noise estimate",
                                   0.0, 1.0)
    relocalise: bool = param(True, "after a loss, try to re-track each lost frame against stored keyframes of the current "
                             "scale (same world frame and scale) before re-initialising")
    reloc_pose_candidates: int = param(2, "relocalisation: keyframes nearest by pose to the last good pose tried first",
                                       0, 50)
    reloc_thumb_candidates: int = param(3, "relocalisation: then the keyframes with the best 16x12 thumbnail SSD "
                                        "against the new frame", 0, 50)
    reloc_min_good_ratio: float = param(0.7, "relocalisation: accept only when the good-residual share is at least "
                                        "this (stricter than min_good_ratio) besides the tracker's lost test",
                                        0.0, 1.0)
    reloc_max_abs_residual: float = param(20.0, "relocalisation: the residual-spread bound of max_abs_residual for a "
                                          "keyframe seen from elsewhere (occlusions, view-dependent shading)", 0.0, 255.0)
    reloc_features: int = param(500, "relocalisation: ORB features per image for a PnP guess against the keyframe's "
                                "depth, tried before the keyframe's own pose (0 = off: own pose only)", 0, 10000)
    reloc_min_inliers: int = param(15, "relocalisation: PnP inliers needed for the feature guess", 6, 10000)
    reloc_cache: int = param(4, "relocalisation: tracking references of keyframes kept built (LRU)", 1, 100)
    motion_hypotheses: bool = param(True, "wide basin: when tracking from the first guess is lost or its coarsest-level "
                                    "energy is far above the recent frames', retry the coarsest level from several "
                                    "motion hypotheses (velocity x1/x2/x0.5, zero motion, the reference's pose, "
                                    "26 small rotations)")
    hypothesis_residual_factor: float = param(4.0, "wide basin: a coarsest-level energy above this times the recent "
                                              "frames' median triggers (and fails) a hypothesis (ICL, normal frames: "
                                              "the ratio's p99 is 2.9, its maximum 3.7)", 1.0, 100.0)
    hypothesis_rotation_deg: float = param(2.0, "wide basin: angle of the 26 rotation hypotheses (0 = none)", 0.0, 45.0)
    hypothesis_window: int = param(10, "wide basin: recent frames whose coarsest-level energies form the median",
                                   1, 1000)
    hypothesis_min_energy: float = param(1.0, "wide basin: a coarsest-level energy below this (residuals at the noise "
                                         "level) never triggers the hypotheses (a still camera's tiny energies "
                                         "fluctuate by more than the factor)", 0.0, 1e6)
    hypothesis_improvement: float = param(0.8, "wide basin: a tracked (not lost) first result is replaced only by a "
                                          "hypothesis whose residual is below this share of it", 0.0, 1.0)
    hypothesis_min_history: int = param(3, "wide basin: frames tracked on the current map before hypotheses are tried",
                                        1, 1000)
