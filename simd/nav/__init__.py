"""Navigation: costmaps, planning, fleet traffic and path following for the robots the daemon
simulates; knows the core, no transport."""
