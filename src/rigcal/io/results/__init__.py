"""What calibration produces: result files, written and read back, and their exports.

* :mod:`.calibration` - a relative calibration (``calibration.yaml``/JSON, per-sensor YAML,
  ROS 1 launch);
* :mod:`.absolute` - an absolute calibration (``absolute.yaml``/JSON, launch files);
* :mod:`.calibration_files` - any of those (or the original tool's) read back as transforms;
* :mod:`.tf_export` - static transforms for ROS 1 / ROS 2 launch, YAML and JSON;
* :mod:`.urdf` - URDF parsing, forward kinematics and joint-origin updates.
"""
