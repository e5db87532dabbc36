"""Adapters: map the engine to the outside world (the fleet protocol over zenoh today)."""
