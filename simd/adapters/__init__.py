"""Adapters: map the engine to the outside world: the fleet protocol over zenoh (fleet/) and ROS 2
over rmw_zenoh (ros2/)."""
