"""Files: ROS bags (rosbags)."""
