"""`gym.make("mikt/NAME", ...)` cannot swap the body: the spec name is bound at registration, and
keywords other than max_episode_steps and render_mode are refused, naming them."""

import gymnasium as gym
import pytest

import miktcli.gym  # noqa: F401 - registers mikt/NAME
from miktcli.errors import MiktError


@pytest.mark.parametrize("kwargs", [{"name": "ant"}, {"name": "centipede-eight", "legs": 4}, {"frobnicate": 1}])
def test_keywords_that_would_change_the_body_are_refused(kwargs):
    with pytest.raises(MiktError, match="would change the environment") as caught:
        gym.make("mikt/centipede-eight", **kwargs)
    assert all(k in str(caught.value) for k in kwargs)
    assert isinstance(caught.value, TypeError)  # what Python's own refusal of a keyword would be


def test_the_registered_body_is_the_spec_s():
    env = gym.make("miktcli.gym:mikt/centipede-eight", max_episode_steps=3)
    assert env.observation_space.shape == gym.make("mikt/centipede-eight").observation_space.shape
    assert env.spec.max_episode_steps == 3
    assert env.observation_space.shape != gym.make("mikt/ant").observation_space.shape
