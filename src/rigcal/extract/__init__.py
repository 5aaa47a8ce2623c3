"""Mocap-guided measurement extractors (Charron et al., "A Target-Based Extrinsic Calibration
Framework for Non-Overlapping Camera-Lidar Systems Using a Motion Capture System", III-C).

The motion capture system predicts every target's pose in every sensor frame
(``T_sensor_target_expected``); the extractors use it to skip frames where the target is out of
view or moving, to search only a region around the prediction (wider when the initial
calibration is less certain), to pick the right cluster and to resolve symmetric orderings.

* :mod:`~rigcal.extract.guidance` - field-of-view and motion checks, crop regions;
* :mod:`~rigcal.extract.camera` - checkerboard corners (+ PnP, + outline), coloured silhouette;
* :mod:`~rigcal.extract.lidar` - crop, Euclidean clustering, cluster choice, ICP, keypoints;
* :mod:`~rigcal.extract.icp` - robust point-to-point / point-to-plane ICP;
* :mod:`~rigcal.extract.result` - :class:`Measurement` or :class:`ExtractionFailure` (with a
  reason code from :data:`REASONS`), never a bare bool.

OpenCV is imported only by :mod:`~rigcal.extract.camera`.
"""

from rigcal.extract.guidance import (
    CropBox,
    MotionCheck,
    PixelBox,
    PoseUncertainty,
    ViewCheck,
    box_from_points,
    camera_view,
    expected_image_box,
    lidar_crop_box,
    lidar_view,
    motion_check,
    relative_speeds,
)
from rigcal.extract.icp import (
    IcpOptions,
    IcpResult,
    PreparedTemplate,
    icp_align,
    prepare_template,
)
from rigcal.extract.lidar import (
    ClusterScore,
    LidarSpec,
    cluster_tolerance,
    euclidean_clusters,
    extract_lidar_target,
    extract_target_lidar,
    ring_ends,
    score_clusters,
)
from rigcal.extract.result import (
    REASONS,
    ExtractionFailure,
    ExtractionResult,
    Measurement,
)

__all__ = [
    "REASONS",
    "ClusterScore",
    "CropBox",
    "ExtractionFailure",
    "ExtractionResult",
    "IcpOptions",
    "IcpResult",
    "LidarSpec",
    "Measurement",
    "MotionCheck",
    "PixelBox",
    "PoseUncertainty",
    "PreparedTemplate",
    "ViewCheck",
    "box_from_points",
    "camera_view",
    "cluster_tolerance",
    "euclidean_clusters",
    "expected_image_box",
    "extract_lidar_target",
    "extract_target_lidar",
    "icp_align",
    "lidar_crop_box",
    "lidar_view",
    "motion_check",
    "prepare_template",
    "relative_speeds",
    "ring_ends",
    "score_clusters",
]
