"""Raw sensor data over time: ROS bags and folders of files, read into :mod:`rigcal.recording`
frames and written from them.

* :mod:`.bag` - ROS 1 / ROS 2 bags (through rosbags);
* :mod:`.folder` - a folder with one subfolder per sensor and one file per frame (and
  ``open_any``, a bag or a folder);
* :mod:`.pointcloud2` - ``sensor_msgs/PointCloud2`` messages <-> point cloud frames.
"""
