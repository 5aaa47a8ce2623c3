"""Raw sensor data over time: ROS bags and folders of files, read into :mod:`rigcal.recording`
frames and written from them.

* :mod:`.open_any` - open a path as whichever recording it is (the usual entry point);
* :mod:`.bag` - ROS 1 / ROS 2 bags (through rosbags);
* :mod:`.folder` - a folder with one subfolder per sensor and one file per frame;
* :mod:`.pointcloud2` - ``sensor_msgs/PointCloud2`` messages <-> point cloud frames;
* :mod:`.images` - PNG/JPEG bytes <-> pixels, for both kinds of recording.
"""
