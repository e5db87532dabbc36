"""fleet-map: occupancy maps from the fleet's scans (the grid, and the command line)."""
