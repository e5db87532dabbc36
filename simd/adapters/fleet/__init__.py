"""The fleet protocol adapter: the daemon's zenoh entities, requests in, messages out."""
