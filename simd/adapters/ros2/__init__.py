"""The ROS 2 adapter: the fleet as rmw_zenoh's wire shows it to ROS 2 tools (docs/ros2.md)."""
