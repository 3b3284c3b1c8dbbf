"""Importing this module registers every environment spec with gymnasium as `mikt/NAME`.

Gymnasium 1.x removed the entry-point plugin system of gym 0.2x; its way to make a third-party env without an
explicit import is the module prefix, which imports the module first:

    import gymnasium as gym
    env = gym.make("miktcli.gym:mikt/centipede-eight", max_episode_steps=500, render_mode="rgb_array")

This module is that hook. Once it is imported (by the prefix, or by hand), `gym.make("mikt/centipede-eight")`
works as well. `max_episode_steps` and `render_mode` pass through `gym.make`; other keywords are refused.
"""

from miktcli.envs.factory import register_with_gymnasium

ENV_IDS = register_with_gymnasium()
