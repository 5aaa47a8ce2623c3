"""Reading and writing rigcal's files: the only package that touches the file system.

Every format has a pure parser (text in, immutable value out) and a thin wrapper that reads the
file; writers produce text and write it atomically (:mod:`rigcal.io.atomic`). Every user mistake
raises :class:`rigcal.errors.InputError` with a one-line message naming the file and field.

* :mod:`rigcal.io.detections_csv` - the original tool's detection CSVs;
* :mod:`rigcal.io.accumulator` - the original tool's ROS accumulator YAML;
* :mod:`rigcal.io.ignore` - the original tool's ignore file (boards to leave out per sensor);
* :mod:`rigcal.io.manifest` - ``rig.yaml``, a dataset manifest;
* :mod:`rigcal.io.results` - calibration results (YAML/JSON, per-sensor YAML, ROS 1 launch).
"""
