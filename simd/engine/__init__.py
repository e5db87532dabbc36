"""The engine: the loop that owns the simulation (engine.py), and the seam its adapters plug
into (ports.py)."""

from simd.engine.engine import Engine

__all__ = ["Engine"]
