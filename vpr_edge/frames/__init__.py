"""Frame sources: where a stream's or a route's frames come from, as ``Frame`` records (index, name, image or
the error that kept it from decoding, stamp): ``frame`` the record, ``images`` folders, videos, cameras and
network streams (``open_stream``, ``list_images``), ``bags`` ROS 1 / ROS 2 bags and MCAP files (rosbags).
Each module is imported where it is used (OpenCV and rosbags load only with them)."""
