"""Motion capture: tracked-body pose streams and the initial extrinsics they are combined with.

Frames follow Charron et al. (section III-A): ``M`` the stationary mocap (map) frame, ``R`` the
robot body tracked by the mocap system, ``T`` a target. A :class:`PoseStream` of the robot holds
``T_M_R`` over time, one of a target ``T_M_T``; :class:`Extrinsics` holds fixed transforms such
as ``T_R_lidar`` (initial guesses) and answers ``lookup(to, from)``.

* :mod:`rigcal.mocap.streams` - :class:`PoseStream`, :func:`interpolate`, CSV and bag readers;
* :mod:`rigcal.mocap.extrinsics` - :class:`Extrinsics`, the original tool's JSON, static TF.
"""

from rigcal.mocap.extrinsics import (
    Extrinsics,
    extrinsics_json_text,
    parse_extrinsics_json,
    read_extrinsics_from_bag,
    read_extrinsics_json,
    write_extrinsics_json,
)
from rigcal.mocap.streams import (
    DEFAULT_MAX_GAP_S,
    PoseSources,
    PoseStream,
    interpolate,
    list_pose_sources,
    matrix_to_quat_xyzw,
    parse_pose_csv,
    pose_csv_text,
    quat_xyzw_to_matrix,
    read_pose_csv,
    read_pose_topics,
    read_tf_streams,
    write_pose_csv,
)

__all__ = [
    "DEFAULT_MAX_GAP_S",
    "Extrinsics",
    "PoseSources",
    "PoseStream",
    "extrinsics_json_text",
    "interpolate",
    "list_pose_sources",
    "matrix_to_quat_xyzw",
    "parse_extrinsics_json",
    "parse_pose_csv",
    "pose_csv_text",
    "quat_xyzw_to_matrix",
    "read_extrinsics_from_bag",
    "read_extrinsics_json",
    "read_pose_csv",
    "read_pose_topics",
    "read_tf_streams",
    "write_extrinsics_json",
    "write_pose_csv",
]
