"""Reinforcement-learning environments on fleetsim's simulation core (docs/learning.md).

Importing this package registers them with Gymnasium::

    import gymnasium
    import learn  # noqa: F401  (registers fleetsim/Navigate-v0)

    env = gymnasium.make("fleetsim/Navigate-v0", world="turtlebot3_world", model="burger")

They run the simulation in the calling process: no daemon, no network.
"""

try:
    from gymnasium.envs.registration import register
except ImportError as e:  # installed without the extra: say how to get it
    raise ImportError("fleetsim's learning environments need gymnasium and pettingzoo: "
                      "pip install -e '.[learn]' (./test installs them)") from e  # fmt: skip

register(id="fleetsim/Navigate-v0", entry_point="learn.navigate:NavigateEnv")
