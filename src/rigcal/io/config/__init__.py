"""What rigcal is told about the rig before it calibrates: how to detect, the cameras'
intrinsics, the mocap target.

* :mod:`.rig_config` - ``detect_rig.yaml``: where each sensor's raw data is and how to detect;
* :mod:`.intrinsics` - the ROS camera calibrator's INI and ``camera_info`` YAML;
* :mod:`.camchain` - Kalibr camchains and the original tool's camera files;
* :mod:`.vicon_json` - the original mocap tool's target definitions and optimizer settings.
"""
