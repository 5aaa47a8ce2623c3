"""Raw sensor data simulation: point clouds, images, stereo pairs and radar detection lists
of a circle board in a simple world (ground, back wall), as :mod:`rigcal.recording` frames.

* :mod:`~rigcal.sim.raw.scene` - the board, ground and wall; analytic ray casting;
* :mod:`~rigcal.sim.raw.lidar` - spinning multi-beam lidars (HDL-64E-, VLP-16-like);
* :mod:`~rigcal.sim.raw.camera` - pinhole + radtan cameras and rectified stereo pairs;
* :mod:`~rigcal.sim.raw.radar` - 2D / 3D radars: corner reflector plus clutter;
* :mod:`~rigcal.sim.raw.recording` - time series over several board placements, with truth.
"""

from rigcal.sim.raw.camera import PinholeRadtanCamera, StereoCamera, render, render_stereo
from rigcal.sim.raw.lidar import LidarModel, hdl64e, scan, vlp16
from rigcal.sim.raw.radar import (
    RadarModel,
    automotive_2d,
    automotive_3d,
    detections,
    reflector_visible,
)
from rigcal.sim.raw.recording import (
    DEFAULT_RATE_HZ,
    BoardTimeline,
    RawSensor,
    SimRecording,
    frame_times_ns,
    iter_recording,
    make_timeline,
    prius_like_raw_rig,
    raw_rig_placements,
    scene_for_placements,
    simulate_recording,
    small_raw_rig,
)
from rigcal.sim.raw.scene import (
    GROUND_MATERIAL,
    PLATE_MATERIAL,
    SURFACE_GROUND,
    SURFACE_NONE,
    SURFACE_PLATE,
    SURFACE_WALL,
    WALL_MATERIAL,
    Material,
    RayHits,
    Scene,
)

__all__ = [
    "BoardTimeline",
    "DEFAULT_RATE_HZ",
    "GROUND_MATERIAL",
    "LidarModel",
    "Material",
    "PLATE_MATERIAL",
    "PinholeRadtanCamera",
    "RadarModel",
    "RawSensor",
    "RayHits",
    "SURFACE_GROUND",
    "SURFACE_NONE",
    "SURFACE_PLATE",
    "SURFACE_WALL",
    "Scene",
    "SimRecording",
    "StereoCamera",
    "WALL_MATERIAL",
    "automotive_2d",
    "automotive_3d",
    "detections",
    "frame_times_ns",
    "hdl64e",
    "iter_recording",
    "make_timeline",
    "prius_like_raw_rig",
    "raw_rig_placements",
    "reflector_visible",
    "render",
    "render_stereo",
    "scan",
    "scene_for_placements",
    "simulate_recording",
    "small_raw_rig",
    "vlp16",
]
