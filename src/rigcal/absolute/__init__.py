"""The body frame from an external measurement (wheels, ground plane, markers on the vehicle).

Relative calibration gives every sensor's pose in a reference sensor's frame; this package ties
those poses to the vehicle body frame (``T_body_sensor``), which is what a URDF or a TF tree
needs (see :mod:`rigcal.io.results.urdf` and :mod:`rigcal.io.results.tf_export`).

* :mod:`~rigcal.absolute.labels` - labels files (YAML / CSV), wheel centres from single clicks
  or rim circles (robust 3D circle fit), markers, the ground plane of the external scan;
* :mod:`~rigcal.absolute.body_frame` - the body frame (origin below the rear axle centre on the
  ground, X forward, Y left, Z up) in the external frame, and ``T_body_sensor``;
* :mod:`~rigcal.absolute.evaluate` - checks: the ground-normal angle (eq. 13), the yaw error
  from a straight drive past poles, labelling repeatability (Table IV).

See ``docs/absolute.md``.
"""

from rigcal.absolute.body_frame import (
    BODY_FRAME,
    ORIGINS,
    BodyFrame,
    body_frame_from_labels,
    body_frame_from_markers,
    body_frame_from_reference_points,
    body_frame_from_wheels,
    sensor_in_body,
    sensors_in_body,
)
from rigcal.absolute.evaluate import (
    GroundNormalCheck,
    Pole,
    Repeatability,
    YawDrift,
    extract_poles,
    ground_normal_angle,
    labelling_repeatability,
    track_poles,
    yaw_from_pole_tracks,
    yaw_from_straight_drive,
)
from rigcal.absolute.labels import (
    MARKER_PREFIX,
    WHEEL_NAMES,
    Circle3D,
    GroundPlane,
    LabelSet,
    WheelCentre,
    fit_circle_3d,
    fit_ground_plane,
    format_labels_csv,
    format_labels_yaml,
    parse_labels_csv,
    parse_labels_yaml,
    wheel_centre,
    wheel_centres,
)

__all__ = [
    "BODY_FRAME",
    "BodyFrame",
    "Circle3D",
    "GroundNormalCheck",
    "GroundPlane",
    "LabelSet",
    "MARKER_PREFIX",
    "ORIGINS",
    "Pole",
    "Repeatability",
    "WHEEL_NAMES",
    "WheelCentre",
    "YawDrift",
    "body_frame_from_labels",
    "body_frame_from_markers",
    "body_frame_from_reference_points",
    "body_frame_from_wheels",
    "extract_poles",
    "fit_circle_3d",
    "fit_ground_plane",
    "format_labels_csv",
    "format_labels_yaml",
    "ground_normal_angle",
    "labelling_repeatability",
    "parse_labels_csv",
    "parse_labels_yaml",
    "sensor_in_body",
    "sensors_in_body",
    "track_poles",
    "wheel_centre",
    "wheel_centres",
    "yaw_from_pole_tracks",
    "yaw_from_straight_drive",
]
