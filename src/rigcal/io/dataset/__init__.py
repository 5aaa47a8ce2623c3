"""Detections ready to calibrate: the ``rig.yaml`` manifest and the files it names, read into a
:class:`rigcal.dataset.Dataset`.

* :mod:`.manifest` - ``rig.yaml``: the sensors, their detection files, board and ignore file;
* :mod:`.detections_csv` - the original tool's detection CSVs;
* :mod:`.accumulator` - the original tool's ROS accumulator YAML;
* :mod:`.ignore` - the original tool's ignore file (boards to leave out per sensor).
"""
