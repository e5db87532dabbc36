"""Wire codecs: core state to protocol messages, as bytes (no transport here).

The odometry packer's C twin is registered here, with the core's registry of compiled fast
paths (simd/core/native.py), before any module of the wire asks for it.
"""

from simd.core import native

native.register("odompack", native.Kernel("simd.wire._odompack", "simd/wire/_odompack.c"))
