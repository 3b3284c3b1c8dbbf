"""Policies trained elsewhere, read without ever unpickling: Stable-Baselines3 PPO zips and CleanRL models.

Stable-Baselines3 saves a zip of `data` (JSON; objects it could not express in JSON are cloudpickled under
`:serialized:` keys, next to their string forms), `policy.pth` (the policy's state dict, torch.save) and more.
We read `data` as plain JSON and never touch a `:serialized:` value, and load `policy.pth` with
`torch.load(weights_only=True)`, which refuses anything but tensors and plain containers. CleanRL's
`ppo_continuous_action.py` saves `agent.state_dict()` (`.cleanrl_model`), read the same way.

Supported shapes (anything else is refused with a one-line error):
- SB3 `MlpPolicy` with separate policy and value networks (`mlp_extractor.policy_net.*`, `.value_net.*`,
  `action_net`, `value_net`, `log_std`), tanh or relu (read from the JSON string of `policy_kwargs`), and no
  parameters in its features extractor (the default `FlattenExtractor`). A shared trunk
  (`mlp_extractor.shared_net`, SB3 < 1.8) is refused: MIKT mixes the policy's and the value's own layers.
- CleanRL `Agent` of `ppo_continuous_action.py`: `actor_mean` and `critic` `nn.Sequential` MLPs (Linear at even
  indices, tanh between unless `--activation relu`) and `actor_logstd` of shape (1, act_dim).
Observation statistics live outside both files (SB3's VecNormalize pickle, CleanRL's NormalizeObservation
wrapper): pass them as numbers (a JSON file with `mean` and `var` lists, optionally `count`). Without them the
teacher sees raw observations (mean 0, var 1, and no clipping: the card's `obs_clip` is None), as it did
without VecNormalize. Where a file cannot tell (CleanRL's activation, an SB3 zip without `activation_fn`), the
card's `imported_from` records what was assumed or given rather than read.
"""

from __future__ import annotations

import hashlib
import io
import json
import re
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from miktcli import limits
from miktcli.engine.policies import GaussianActorCritic
from miktcli.errors import MiktError
from miktcli.limits import read_file_bounded

FORMATS = ("sb3", "cleanrl")
ACTIVATIONS = ("tanh", "relu")
_LAYER = re.compile(r"^(?P<net>.+)\.(?P<index>\d+)\.(?P<param>weight|bias)$")


@dataclass
class ImportedPolicy:
    """A foreign policy mapped onto this project's actor-critic, with where it came from."""

    policy: GaussianActorCritic
    activation: str
    source: dict[str, Any] = field(default_factory=dict)


def _read_member(archive: zipfile.ZipFile, name: str, maximum: int, where: str) -> bytes:
    """One member, refused from the size its header declares, then counted while inflating (a header may
    lie): a member that inflates past `maximum` never sits whole in memory."""
    what = f"{where}: member '{name}'"
    info = archive.getinfo(name)
    limits.check_declared_size(what, info.file_size, maximum)
    with archive.open(info) as stream:
        return limits.read_bounded(stream, what, maximum)


def _check_torch_archive(data: bytes, where: str) -> None:
    """torch.save writes a zip of uncompressed members (the pickle and one per storage): a compressed or
    oversized member is not torch's and could inflate inside torch.load, so it is refused before loading."""
    if not zipfile.is_zipfile(io.BytesIO(data)):
        return  # torch's legacy format: one stream whose storages are within these (bounded) bytes
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            infos = archive.infolist()
    except (zipfile.BadZipFile, ValueError) as err:
        raise MiktError(f"{where}: not a readable torch file: {err}") from None
    packed = [i.filename for i in infos if i.compress_type != zipfile.ZIP_STORED]
    if packed:
        raise MiktError(f"{where}: member '{packed[0]}' is compressed; torch.save stores its tensors uncompressed")
    limits.check_declared_size(f"{where}: its tensors", sum(i.file_size for i in infos),
                               limits.MAX_TENSOR_FILE_BYTES)


def _load_weights(data: bytes, where: str) -> dict[str, torch.Tensor]:
    _check_torch_archive(data, where)
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols beside the error we give
            warnings.filterwarnings("ignore", message=".*pickle protocol", category=UserWarning)
            state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - torch raises several types; weights_only refusals among them
        raise MiktError(f"{where}: not a plain state dict of tensors (refused without unpickling: "
                        f"{type(err).__name__})") from None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise MiktError(f"{where}: expected a state dict of tensors")
    return dict(state)


def _stack(state: dict[str, torch.Tensor], prefix: str, where: str) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The Linear layers of an nn.Sequential saved under `prefix`, in order."""
    layers: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in state.items():
        if key.startswith(prefix + "."):
            m = _LAYER.match(key)
            if not m or m.group("net") != prefix:
                raise MiktError(f"{where}: unexpected tensor '{key}' in '{prefix}'")
            layers.setdefault(int(m.group("index")), {})[m.group("param")] = value
    if not layers:
        raise MiktError(f"{where}: no layers under '{prefix}'")
    out = []
    for index in sorted(layers):
        if set(layers[index]) != {"weight", "bias"}:
            raise MiktError(f"{where}: layer '{prefix}.{index}' lacks a weight or a bias")
        weight, bias = layers[index]["weight"], layers[index]["bias"]
        if weight.dim() != 2 or bias.dim() != 1:
            raise MiktError(f"{where}: layer '{prefix}.{index}' has a {weight.dim()}-D weight and a {bias.dim()}-D "
                            "bias; a Linear layer has 2-D and 1-D")
        out.append((layers[index]["weight"], layers[index]["bias"]))
    return out


def _assemble(pi_hidden: list[tuple], pi_head: tuple, vf_hidden: list[tuple], vf_head: tuple,
              log_std: torch.Tensor, activation: str, where: str) -> GaussianActorCritic:
    if not pi_hidden or not vf_hidden:  # MIKT mixes hidden layers: a policy without one has none to share
        raise MiktError(f"{where}: the policy and value networks need at least one hidden layer each")
    obs_dim, act_dim = pi_hidden[0][0].shape[1], pi_head[0].shape[0]
    sizes_pi = [w.shape[0] for w, _ in pi_hidden]
    sizes_vf = [w.shape[0] for w, _ in vf_hidden]
    if vf_hidden[0][0].shape[1] != obs_dim or vf_head[0].shape[0] != 1:
        raise MiktError(f"{where}: the value network reads {vf_hidden[0][0].shape[1]} inputs (policy: {obs_dim}) "
                        f"and gives {vf_head[0].shape[0]} outputs (expected 1)")
    policy = GaussianActorCritic(obs_dim, act_dim, sizes_pi, sizes_vf, activation)
    state = {"log_std": log_std.reshape(-1), "obs_normalizer.mean": torch.zeros(obs_dim, dtype=torch.float64),
             "obs_normalizer.var": torch.ones(obs_dim, dtype=torch.float64),
             "obs_normalizer.count": torch.tensor(0.0, dtype=torch.float64)}
    for net, hidden, head in (("pi", pi_hidden, pi_head), ("vf", vf_hidden, vf_head)):
        for j, (w, b) in enumerate(hidden):
            state[f"{net}.hidden.{j}.weight"], state[f"{net}.hidden.{j}.bias"] = w, b
        state[f"{net}.head.weight"], state[f"{net}.head.bias"] = head
    not_real = [k for k, v in state.items() if not v.is_floating_point()]
    if not_real:  # a complex log_std would pass isfinite and be cast silently to its real part
        raise MiktError(f"{where}: tensor '{not_real[0]}' is {state[not_real[0]].dtype}; policies hold real "
                        "floating-point tensors")
    not_finite = [k for k, v in state.items() if not torch.isfinite(v).all()]
    if not_finite:  # a diverged policy would act NaN: refuse it before it enters the registry
        raise MiktError(f"{where}: weights for '{not_finite[0]}' hold NaN or infinite values")
    try:
        policy.load_state_dict({k: v.float() if k.startswith(("pi.", "vf.", "log_std")) else v
                                for k, v in state.items()})
    except RuntimeError as err:
        raise MiktError(f"{where}: layer shapes do not chain: {str(err).splitlines()[-1].strip()}") from None
    return policy


def read_sb3_zip(path: Path, activation: str | None = None) -> ImportedPolicy:
    where = str(path)
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
            if "policy.pth" not in names or "data" not in names:
                raise MiktError(f"{where}: not a Stable-Baselines3 model zip (no 'data' or 'policy.pth')")
            data_text = _read_member(archive, "data", limits.MAX_SB3_DATA_BYTES, where).decode("utf-8")
            weights = _read_member(archive, "policy.pth", limits.MAX_TENSOR_FILE_BYTES, where)
            version = _read_member(archive, "_stable_baselines3_version", limits.MAX_SMALL_MEMBER_BYTES,
                                   where).decode().strip() if "_stable_baselines3_version" in names else None
    except (zipfile.BadZipFile, OSError, UnicodeDecodeError, zlib.error, RuntimeError, NotImplementedError) as err:
        # damaged deflate streams (zlib.error), encrypted members (RuntimeError), unknown compressions
        raise MiktError(f"{where}: not a readable zip: {type(err).__name__}: {err}") from None
    try:
        data = json.loads(data_text)  # plain JSON: `:serialized:` values stay base64 strings, never unpickled
    except (json.JSONDecodeError, RecursionError) as err:
        raise MiktError(f"{where}: its 'data' is not JSON: {err}") from None
    kwargs = data.get("policy_kwargs") if isinstance(data, dict) else None
    activation_text = str(kwargs.get("activation_fn", "")) if isinstance(kwargs, dict) else ""
    # SB3 records the class as "<class 'torch.nn.modules.activation.ReLU'>": its exact name decides, since
    # LeakyReLU, ReLU6 or Tanhshrink are other functions that merely contain "ReLU" or "Tanh"
    class_name = activation_text.strip("<>").removeprefix("class ").strip("'\"").rsplit(".", 1)[-1]
    if class_name in ("ReLU", "Tanh"):
        read = class_name.lower()
        if activation is not None and activation != read:
            raise MiktError(f"{where}: --activation {activation} contradicts the file, whose policy_kwargs name "
                            f"{class_name}", hint="leave --activation out for SB3 zips that record it")
        activation, how = read, "read from policy_kwargs"
    elif activation_text == "":
        how = "given (--activation)" if activation else "assumed: PPO MlpPolicy's default (not in policy_kwargs)"
        activation = activation or "tanh"
    else:
        raise MiktError(f"{where}: activation {activation_text!r} is not supported (tanh or relu)")
    state = _load_weights(weights, f"{where}: policy.pth")
    if any(k.startswith("mlp_extractor.shared_net") for k in state):
        raise MiktError(f"{where}: the policy and value networks share a trunk (mlp_extractor.shared_net); "
                        "MIKT mixes each network's own hidden layers, so only separate networks can be imported")
    extractor = [k for k in state if "features_extractor" in k]
    if extractor:
        raise MiktError(f"{where}: its features extractor has parameters ('{extractor[0]}'); only MlpPolicy's "
                        "flatten extractor is supported")
    known = ("mlp_extractor.policy_net.", "mlp_extractor.value_net.", "action_net.", "value_net.", "log_std")
    unknown = [k for k in state if not k.startswith(known)]
    if unknown:
        raise MiktError(f"{where}: unexpected tensor '{unknown[0]}' for an MlpPolicy")
    for key in ("log_std", "action_net.weight", "action_net.bias", "value_net.weight", "value_net.bias"):
        if key not in state:
            raise MiktError(f"{where}: tensor '{key}' is missing (a Gaussian MlpPolicy has it)")
    policy = _assemble(
        _stack(state, "mlp_extractor.policy_net", where), (state["action_net.weight"], state["action_net.bias"]),
        _stack(state, "mlp_extractor.value_net", where), (state["value_net.weight"], state["value_net.bias"]),
        state["log_std"], activation, where)
    return ImportedPolicy(policy, activation, {"format": "sb3", "sb3_version": version, "activation": how})


def read_cleanrl(path: Path, activation: str | None = None) -> ImportedPolicy:
    """A CleanRL model's state dict cannot tell its activation: `activation` says it (tanh, the script's, when
    None, and the card records that it was assumed)."""
    where = str(path)
    state = _load_weights(read_file_bounded(path, where, limits.MAX_TENSOR_FILE_BYTES), where)
    unknown = [k for k in state if not k.startswith(("actor_mean.", "critic.", "actor_logstd"))]
    if unknown:
        raise MiktError(f"{where}: unexpected tensor '{unknown[0]}' for ppo_continuous_action's Agent")
    if "actor_logstd" not in state:
        raise MiktError(f"{where}: tensor 'actor_logstd' is missing")
    actor, critic = _stack(state, "actor_mean", where), _stack(state, "critic", where)
    how = "given (--activation)" if activation else "assumed: ppo_continuous_action.py's tanh (a state dict " \
        "cannot tell)"
    activation = activation or "tanh"
    policy = _assemble(actor[:-1], actor[-1], critic[:-1], critic[-1], state["actor_logstd"], activation, where)
    return ImportedPolicy(policy, activation, {"format": "cleanrl", "activation": how})


def _numbers(value: Any, key: str) -> Any:
    """JSON numbers only: Python reads `true` as 1, which would pass silently into a normaliser."""
    items = value if isinstance(value, list) else [value]
    if any(isinstance(v, bool) for v in items):
        raise TypeError(f"'{key}' holds true or false, not a number")
    return value


def read_obs_stats(path: Path, obs_dim: int) -> dict[str, torch.Tensor]:
    """`{"mean": [...], "var": [...], "count": n}` (count optional) as the normaliser's buffers."""
    try:
        data = json.loads(read_file_bounded(path, str(path), limits.MAX_JSON_BYTES).decode("utf-8"))
        mean = torch.tensor(_numbers(data["mean"], "mean"), dtype=torch.float64)
        var = torch.tensor(_numbers(data["var"], "var"), dtype=torch.float64)
        count = torch.tensor(float(_numbers(data.get("count", 1e6), "count")), dtype=torch.float64)
    except (json.JSONDecodeError, RecursionError, KeyError, TypeError, ValueError, OverflowError,
            UnicodeDecodeError) as err:
        raise MiktError(f"{path}: expected JSON with 'mean' and 'var' lists of numbers (and optionally "
                        f"'count'): {type(err).__name__}: {err}") from None
    if mean.shape != (obs_dim,) or var.shape != (obs_dim,):
        raise MiktError(f"{path}: 'mean' has shape {tuple(mean.shape)} and 'var' {tuple(var.shape)}; the policy "
                        f"reads {obs_dim} dims, so both must be flat lists of {obs_dim} numbers")
    if not bool(torch.isfinite(mean).all() and torch.isfinite(var).all() and (var >= 0).all()):
        raise MiktError(f"{path}: statistics must be finite, with var ≥ 0")
    if not (torch.isfinite(count) and count > 0):
        raise MiktError(f"{path}: 'count' must be a positive finite number, got {count.item()}")
    return {"mean": mean, "var": var, "count": count}


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):  # in pieces: a zip may be far larger than its members
            h.update(chunk)
    return h.hexdigest()


def read_foreign_policy(path: Path, fmt: str, obs_stats: Path | None,
                        activation: str | None = None) -> ImportedPolicy:
    if not Path(path).is_file():
        raise MiktError(f"{path}: " + ("a folder, not a model file" if Path(path).is_dir() else "no such file"))
    if fmt not in FORMATS:
        raise MiktError(f"unknown format '{fmt}'; known: {', '.join(FORMATS)}")
    if activation is not None and activation not in ACTIVATIONS:
        raise MiktError(f"unknown activation '{activation}'; known: {', '.join(ACTIVATIONS)}")
    imported = read_sb3_zip(path, activation) if fmt == "sb3" else read_cleanrl(path, activation)
    imported.source["file"] = Path(path).name
    imported.source["file_sha256"] = _file_sha256(Path(path))
    if obs_stats is not None:
        stats = read_obs_stats(obs_stats, imported.policy.obs_normalizer.mean.shape[0])
        with torch.no_grad():
            for key, value in stats.items():
                getattr(imported.policy.obs_normalizer, key).copy_(value)
        imported.source["obs_stats"] = Path(obs_stats).name
    else:  # what the policy saw in training is unknown: raw observations, as without VecNormalize
        imported.source["obs_stats"] = "none given: raw observations, not clipped"
    return imported
