"""Navigation: costmaps, planning, fleet traffic and path following for the robots the daemon
simulates; knows the core, no transport.

The distance fields' C twin is registered here, with the core's registry of compiled fast
paths (simd/core/native.py), before any module of navigation asks for it.
"""

from simd.core import native

native.register("cellpaths", native.Kernel("simd.nav._cellpaths", "simd/nav/_cellpaths.c"))
