"""fleetsim clients: the Python API, spawner CLI, keyboard teleop and viewer."""

from clients.api import FleetClient, Subscription, wait_until

__all__ = ["FleetClient", "Subscription", "wait_until"]
