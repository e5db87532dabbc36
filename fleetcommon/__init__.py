"""What every fleetsim program shares beside the wire contract (``protocol``): the zenoh flags
and the session config they build (``zenoh_config``), map_server's map files (``mapfile``), the
strict loaders' errors (``files``), the numpy array aliases (``arrays``) and where a point meets
a polyline (``polyline``), and an event a signal handler may set (``signals``). Both the daemon and
the clients import it; it imports neither, nor anything of theirs but the protocol.
"""
