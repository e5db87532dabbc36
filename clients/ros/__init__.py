"""``fleet-ros``: Nav2 files that fit ``simd --ros2`` (nav2_params.py, nav2_files.py) and a smoke
test against a real ROS 2 install (smoke.py, smoke_checks.py); cli.py is the command line."""
