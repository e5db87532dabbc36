"""``fleet-record``: a run recorded as a rosbag2 (``cli``), from the fleet protocol converted to ROS
messages (``fleet_to_ros``) or from a ROS domain (``ros_source``), written by ``bag``."""
