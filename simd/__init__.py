"""simd: the fleetsim simulation daemon (core in world/robots/lidar/sim; network layer in net)."""
