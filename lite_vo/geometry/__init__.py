"""Rigid and similarity transforms: the one place the project's pose conventions are written.

Conventions (pinned by tests/test_geometry.py):

* ``T_a_b`` is a 4x4 homogeneous matrix mapping points from frame b into frame a:
  ``p_a = T_a_b @ p_b``; composition ``T_a_c = T_a_b @ T_b_c``.
* Twists are ordered ``(v, omega)`` (translation part first); Sim(3) tangent vectors are
  ``(v, omega, sigma)`` with scale ``s = exp(sigma)``.
* ``exp_se3(xi)`` maps a twist to a matrix; updates are left-multiplicative:
  ``T <- exp_se3(dxi) @ T``.
* Quaternions are stored in TUM order ``(qx, qy, qz, qw)``, named ``quat_xyzw``.

Every function accepts a single element or a batch with leading dimensions
(``(..., 6)`` twists, ``(..., 4, 4)`` matrices). This package imports only numpy.
"""
from .so3 import exp_so3, hat, log_so3, vee
from .se3 import (
    adjoint_se3,
    compose,
    exp_se3,
    inverse_se3,
    log_se3,
    make_pose,
    project_to_se3,
    transform_points,
)
from .sim3 import adjoint_sim3, exp_sim3, inverse_sim3, log_sim3
from .quaternion import (
    pose_from_tum,
    quat_xyzw_from_rotmat,
    rotmat_from_quat_xyzw,
    tum_from_pose,
)

__all__ = [
    "hat", "vee", "exp_so3", "log_so3",
    "exp_se3", "log_se3", "inverse_se3", "compose", "adjoint_se3", "make_pose", "project_to_se3", "transform_points",
    "exp_sim3", "log_sim3", "inverse_sim3", "adjoint_sim3",
    "quat_xyzw_from_rotmat", "rotmat_from_quat_xyzw", "pose_from_tum", "tum_from_pose",
]
