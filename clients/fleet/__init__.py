"""``fleet`` and ``fleet-spawn``: the fleet's command line (``cli``), what it prints (``output``),
how it plans a spawn (``spawn_plan``) and follows a goal (``goto``)."""
