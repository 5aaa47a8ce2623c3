"""Reading and writing rigcal's files: the only package that touches the file system.

Every format has a pure parser (text in, immutable value out) and a thin wrapper that reads the
file; writers produce text and write it atomically (:mod:`rigcal.io.atomic`). Every user mistake
raises :class:`rigcal.errors.InputError` with a one-line message naming the file and field.

Grouped by what is read or written, in the order data flows through a calibration:

* :mod:`rigcal.io.recordings` - raw sensor data: ROS bags and folder recordings;
* :mod:`rigcal.io.config` - what rigcal is told about the rig: detection config, camera
  intrinsics, mocap targets;
* :mod:`rigcal.io.dataset` - detections ready to calibrate: the ``rig.yaml`` manifest and the
  original tool's detection, accumulator and ignore files;
* :mod:`rigcal.io.results` - calibration results, their ROS/URDF exports and reading them back;
* :mod:`rigcal.io.clouds` - PCD/PLY/NPY point cloud files (frames of folder recordings,
  mocap template clouds).

Shared by all: :mod:`rigcal.io.atomic` (atomic writes), :mod:`rigcal.io.limits` (what a file
may hold before it is trusted) and ``rigcal.io._text`` (reading text and YAML with context).
"""
