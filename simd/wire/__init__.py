"""Wire codecs: core state to protocol messages, as bytes (no transport here).

The C twins of the odometry packer and the robot-list packer are registered here, with the
core's registry of compiled fast paths (simd/core/native.py), before a module of the wire asks.
"""

from simd.core import native

native.register("odompack", native.Kernel("simd.wire._odompack", "simd/wire/_odompack.c"))
native.register("listpack", native.Kernel("simd.wire._listpack", "simd/wire/_listpack.c"))
