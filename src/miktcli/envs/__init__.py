"""Environment specs, the centipede family, and the factory that builds either."""

from miktcli.envs.gl_backend import import_mujoco_without_gl

import_mujoco_without_gl()  # before any module here imports mujoco: its GL backend loads only to render

from miktcli.envs.factory import env_dims, make_env, model_facts, register_with_gymnasium  # noqa: E402
from miktcli.envs.spec import (  # noqa: E402
    CentipedeSpec,
    GymnasiumSpec,
    load_all_specs,
    load_spec,
    parse_spec,
    spec_names,
)

__all__ = [
    "CentipedeSpec", "GymnasiumSpec", "env_dims", "load_all_specs", "load_spec", "make_env", "model_facts",
    "parse_spec", "register_with_gymnasium", "spec_names",
]
