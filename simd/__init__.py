"""simd: the fleetsim simulation daemon: the core (world, robots, lidar, the tick), the engine that runs
it, the wire codecs, navigation and the adapters (fleet protocol, ROS 2); docs/architecture.md."""
