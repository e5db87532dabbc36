"""The simulation core: world, robot table, physics, drive, lidar, models, world files.

Knows no transport and no wire format: the engine runs it, adapters map it to the outside.
"""
