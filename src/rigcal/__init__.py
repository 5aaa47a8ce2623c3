"""rigcal: joint extrinsic calibration of lidar, camera and radar rigs.

Transforms are 4x4 numpy arrays named ``T_to_from``: ``T_to_from @ p_from = p_to``.
See ``docs/conventions.md``.
"""

__version__ = "0.1.0"
