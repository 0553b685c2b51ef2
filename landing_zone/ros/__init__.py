"""The ROS 2 front end: the node, its serialized take and bag playback (the only rclpy users)."""
