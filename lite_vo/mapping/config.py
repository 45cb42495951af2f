"""Mapping parameters (per-pixel inverse-depth filter). Values from ALGORITHM_NOTES.md, made fields.

Imports: the config field helper only (no numpy, no numba).
"""
from __future__ import annotations

from dataclasses import dataclass

from ..config_fields import param


@dataclass(frozen=True)
class MappingConfig:
    """Semi-dense inverse-depth filter at the mapping resolution."""
    # pixel selection
    min_grad: float = param(5.0, "minimum (3x3 max-filtered) gradient magnitude for a hypothesis", 0.0, 255.0)
    min_epl_length: float = param(1.0, "skip stereo when the epipolar line is shorter than this (px)", 0.0, 100.0)
    min_epl_grad_sq: float = param(4.0, "skip when the squared gradient along the epipolar line is below this", 0.0, 1e5)
    min_epl_angle_cos: float = param(0.3, "skip when |cos(angle(gradient, epipolar line))| is below this", 0.0, 1.0)
    # epipolar search
    min_depth: float = param(0.05, "nearest depth searched without a prior (map units)", 1e-4, 100.0)
    max_epl_search: float = param(30.0, "longest searched epipolar segment (px)", 3.0, 1000.0)
    min_epl_search: float = param(3.0, "shortest searched epipolar segment (px)", 0.5, 100.0)
    min_clipped_epl: float = param(8.0, "reject a search line shorter than this after clipping its near end into the image (px)", 0.0, 1000.0)
    search_border: float = param(7.0, "the far end of the search line must be this far inside the image (px)", 2.0, 100.0)
    search_sigmas: float = param(2.0, "search interval is idepth +- this many standard deviations", 0.1, 100.0)
    create_prior_idepth: float = param(1.0, "inverse depth used for the scale change of the 5 samples when no prior exists", 1e-6, 1e4)
    ssd_max: float = param(1300.0, "match threshold on the 5-sample SSD (4x before refinement)", 0.0, 1e7)
    ssd_grad_factor: float = param(20.0, "after refinement reject when best > ssd_max + this*sqrt(grad along line)", 0.0, 1e4)
    ambiguity_factor: float = param(1.5, "reject when the second best SSD is within this factor of the best", 1.0, 100.0)
    min_scale: float = param(0.7, "reject matches with an epipolar scale change below this", 0.01, 1.0)
    max_scale: float = param(1.4, "reject matches with an epipolar scale change above this", 1.0, 100.0)
    subpixel: bool = param(True, "sub-pixel refinement of the match")
    saturation: float = param(250.0, "intensities at or above this are clipped: a patch touching them is not searched, "
                              "reference samples there never match, propagation does not compare them (256 = off)",
                              0.0, 1e6)
    saturation_gain_tol: float = param(0.02, "the clipped-pixel rules apply only between frames whose brightness gain "
                                       "differs by more than this (without an exposure change, the edges of clipped "
                                       "areas are stable and useful)", 0.0, 10.0)
    keep_clipped: bool = param(True, "keep a hypothesis whose pixel is clipped (at or above saturation) and has no "
                               "gradient left, instead of removing it: under auto-exposure a bright region flattens "
                               "for a while and its map would be deleted and rebuilt (ICL with auto-exposure, depth "
                               "start: ATE 2.4 -> 1.1 %)")
    # observation variance (eq. 3.6-3.12)
    sigma_i: float = param(4.0, "image noise std in grey levels for the photometric error", 0.01, 100.0)
    noise_sigma_gain: float = param(1.0, "the photometric variance uses sigma = max(sigma_i, this * the frame's image "
                                    "noise estimate) (0 = constant sigma_i)", 0.0, 10.0)
    geo_error_base: float = param(0.25, "geometric error e = this * (1 + tracking residual of the reference) (px)", 0.0, 100.0)
    subpixel_var: float = param(0.05, "disparity discretisation variance with sub-pixel refinement (px^2)", 0.0, 10.0)
    no_subpixel_var: float = param(0.5, "disparity discretisation variance without sub-pixel refinement (px^2)", 0.0, 10.0)
    # fusion and validity
    max_var: float = param(0.25, "largest variance of a new or kept hypothesis (idepth units^2)", 1e-6, 100.0)
    prediction_noise: float = param(1.01, "prior variance inflation before fusion", 1.0, 10.0)
    fail_var_inflation: float = param(1.1, "variance inflation after an inconsistent observation", 1.0, 10.0)
    observe_diff_fac: float = param(1.0, "an observation is inconsistent when this*diff^2 > var_obs + var_prior", 0.0, 100.0)
    validity_inc: float = param(5.0, "validity gained per successful observation", 0.0, 1000.0)
    validity_dec: float = param(5.0, "validity lost per failed search", 0.0, 1000.0)
    validity_max: float = param(5.0, "validity cap: this + validity_max_grad * maxgrad / 255", 0.0, 1e4)
    validity_max_grad: float = param(250.0, "gradient-dependent part of the validity cap", 0.0, 1e5)
    observe_validity: float = param(5.0, "validity of a hypothesis created by stereo", 0.0, 1000.0)
    blacklist_recovery_frames: int = param(4, "every this many iterations each negative blacklist counter rises by 1 (0 = never)", 0, 10000)
    min_blacklist: int = param(-1, "pixels whose blacklist counter fell below this are not searched and need unblacklist_sum to be filled", -1000, 0)
    converged_skip: int = param(2, "after an update whose search line was shorter than min_epl_search, skip this many stereo iterations for the pixel", 0, 1000)
    # propagation
    propagation_sigma: float = param(0.0, "sigma_p^2 added to the variance on propagation", 0.0, 1.0)
    border: float = param(3.0, "drop propagated hypotheses this close to the border (px)", 0.0, 50.0)
    prop_diff_const: float = param(40.0, "propagation intensity check: drop when r^2 > this^2 + prop_diff_grad_fac*|g|^2", 0.0, 255.0)
    prop_diff_grad_fac: float = param(0.25, "gradient-dependent part of the propagation intensity check", 0.0, 100.0)
    prop_merge_fac: float = param(1.0, "colliding hypotheses are fused when this*diff^2 <= var_a + var_b", 0.0, 100.0)
    # initialisation
    init_var: float = param(0.125, "variance of random initialisation and hole filling", 1e-6, 10.0)
    init_validity: float = param(20.0, "validity of initialised hypotheses", 0.0, 1000.0)
    depth_init_var: float = param(1e-4, "variance of hypotheses from a depth image", 1e-9, 10.0)
    random_idepth_min: float = param(0.5, "random initialisation: idepth = this + U(0, random_idepth_range)", 0.0, 1e4)
    random_idepth_range: float = param(1.0, "random initialisation: width of the uniform idepth interval", 0.0, 1e4)
    # regularisation and hole filling
    reg_radius: int = param(2, "regularisation window radius (2 = 5x5)", 0, 10)
    reg_dist_var: float = param(0.005625, "regularisation weight 1/(var + this*dist^2)", 0.0, 10.0)
    reg_diff_fac: float = param(1.0, "neighbours count when this*diff^2 <= var_a + var_b", 0.0, 100.0)
    reg_validity_sum: float = param(24.0, "regularisation keeps a pixel when its neighbours' validity sum reaches this", 0.0, 1e4)
    reg_var_mode: str = param("min", "variance published with the smoothed idepth: smallest compatible neighbour variance (thesis), own, or fused = 1/sum of weights (LSD-SLAM)", choices=("min", "own", "fused"))
    fill_validity_sum: float = param(30.0, "hole filling threshold on the 5x5 validity sum", 0.0, 1e4)
    unblacklist_validity_sum: float = param(100.0, "hole filling threshold for blacklisted pixels", 0.0, 1e5)
    fill_validity: float = param(0.0, "validity of a hypothesis created by hole filling", 0.0, 1000.0)
    # scheduling
    budget_ms: float = param(0.0, "time budget per mapping iteration; limits stereo updates when > 0", 0.0, 10000.0)
    stereo_stride: int = param(1, "search only every k-th stereo candidate per mapping iteration (rotating, so each "
                               "pixel is searched every k-th iteration: more baseline per update, 1/k of the stereo "
                               "cost); the time budget may sub-sample further", 1, 16)
    buffer_size: int = param(12, "past frames kept as stereo references", 1, 200)
