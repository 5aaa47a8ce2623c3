"""Pure, batched numpy geometry: SO(3)/SE(3), alignment, Euler angles, frame-checked transforms.

Conventions (see ``docs/conventions.md``):

* a transform ``T_to_from`` is a (4, 4) array with ``p_to = T_to_from @ p_from``;
* rotation vectors are axis * angle in radians;
* a 6-vector tangent ``xi = (omega, v)`` has the rotation part first;
* poses are perturbed on the right: ``T <- T @ exp(xi)`` (``xi`` in the moving frame);
* roll-pitch-yaw are intrinsic Z-Y'-X'' (yaw about z, then pitch about y, then roll about x),
  ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

No function here mutates its inputs.
"""

from rigcal.geometry.align import kabsch, kabsch_batch, umeyama
from rigcal.geometry.frames import Transform
from rigcal.geometry.se3 import (
    compose,
    from_rt,
    invert,
    se3_exp,
    se3_log,
    transform_points,
)
from rigcal.geometry.so3 import hat, rpy_from_matrix, matrix_from_rpy, so3_exp, so3_log

__all__ = [
    "Transform",
    "compose",
    "from_rt",
    "hat",
    "invert",
    "kabsch",
    "kabsch_batch",
    "matrix_from_rpy",
    "rpy_from_matrix",
    "se3_exp",
    "se3_log",
    "so3_exp",
    "so3_log",
    "transform_points",
    "umeyama",
]
