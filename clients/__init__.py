"""fleetsim clients: the Python API (FleetClient), the fleet CLI, teleop, the viewer, the recorder,
mapping and the ROS helpers; each speaks the protocol only."""

from clients.api import FleetClient, Subscription, wait_until

__all__ = ["FleetClient", "Subscription", "wait_until"]
