"""open_any: a bag or a folder recording behind one call, and the ROS 2 bag without metadata."""

from __future__ import annotations

from pathlib import Path

import pytest

from rigcal.errors import InputError
from rigcal.io.recordings.bag import write_recording
from rigcal.io.recordings.folder import write_folder_recording
from rigcal.io.recordings.open_any import open_any
from rigcal.recording import PointCloudFrame


def test_open_any_dispatches(tmp_path):
    cloud = PointCloudFrame("l", 1, [[1, 2, 3]])
    bag = write_recording(tmp_path / "b", {"/p": [cloud]}, "rosbag2-mcap")
    folder = write_folder_recording(tmp_path / "f", {"p": [cloud]})
    with open_any(bag) as rec:
        assert rec.topics() == {"/p": "sensor_msgs/msg/PointCloud2"}
    with open_any(folder) as rec:
        assert rec.topics() == {"p": "points"}
    with pytest.raises(InputError, match="recording folder not found"):
        open_any(Path(tmp_path / "missing"))


def test_ros2_storage_without_metadata_is_refused(tmp_path):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "bag_0.mcap").write_bytes(b"")
    with pytest.raises(InputError, match=r"looks like a ROS 2 bag \(has bag_0\.mcap\) but "
                                         "metadata.yaml is missing"):
        open_any(tmp_path / "bag")
