"""What runs beside the pipeline on the robot, ROS-free: stamp-ordered input, the live receive
path, snapshots."""
