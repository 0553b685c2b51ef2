"""The front ends over the one pipeline: the ROS 2 node, bag replay, bag play, and the
stamp-ordered stream of clouds and poses the node and replay share."""
