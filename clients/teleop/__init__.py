"""``fleet-teleop``: keyboard teleop, its pure model (``model``: keys, ramps, the screen) beside
the session and the 10 Hz loop (``cli``)."""
