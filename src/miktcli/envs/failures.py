"""An environment that fails while it runs (reset or step) is a problem of its spec, not a bug of mikt: a spec's
kwargs reach the env's constructor, and some break only once the env steps (a string where a range belongs)."""

from __future__ import annotations

from typing import Any

from miktcli.errors import MiktError

_NAME_ATTR = "_mikt_spec_name"  # set on the unwrapped env by make_env: no wrapper layer on the hot path


def remember_spec_name(env: Any, name: str) -> None:
    setattr(env.unwrapped, _NAME_ATTR, name)


def env_failure(env: Any, err: Exception, during: str) -> MiktError:
    """A one-line error naming the spec an env was built from and what it raised."""
    name = getattr(getattr(env, "unwrapped", env), _NAME_ATTR, None)
    what = f"environment '{name}'" if name else "the environment"
    message = str(err).splitlines()[0] if str(err) else ""  # MuJoCo's FatalError: its first line says it all
    return MiktError(f"{what} failed in {during}: {type(err).__name__}" + (f": {message}" if message else ""),
                     hint=f"check its spec (mikt envs show {name}): kwargs can break only when the env runs"
                     if name else "check the environment's spec file")
