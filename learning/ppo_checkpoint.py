"""The PPO checkpoint format ("goflow.ppo/1"): a dict of tensors and plain data, loadable with
torch.load(weights_only=True), that `PPO.state_dict` writes and `PPO.load_state_dict` reads.

Keys: "format", "config" (the PPOConfig fields), "obs_dim", "critic_obs_dim", "action_low",
"action_high", the networks' and optimizer's state dicts ("actor", "critic", "optimizer"), the
normalizers ("obs_rms", "critic_obs_rms", "reward_rms"), the RNG states ("torch_rng", "act_rng",
"numpy_rng") and "counters" (iteration, global_step, gradient_steps). Skill files keep all but
"optimizer".
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import numpy as np
from gymnasium import spaces

from goflow_common.errors import FileFormatError
from goflow_common.files import check_output_file, load_tensors, save_tensors

__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_WHAT",
    "check_loadable",
    "is_checkpoint",
    "read_checkpoint",
    "saved_action_space",
    "saved_config",
    "write_checkpoint",
]

CHECKPOINT_FORMAT = "goflow.ppo/1"
#: How a file of this format is named in error messages.
CHECKPOINT_WHAT = "PPO checkpoint (written by PPO.save)"


def is_checkpoint(state: Any) -> bool:
    """Whether `state` is a dict in this format."""
    return isinstance(state, dict) and state.get("format") == CHECKPOINT_FORMAT


def saved_config(state: dict[str, Any]) -> dict[str, Any]:
    """The PPOConfig fields a checkpoint was written with (hidden_sizes as a tuple)."""
    config = dict(state["config"])
    config["hidden_sizes"] = tuple(config["hidden_sizes"])
    return config


def saved_action_space(state: dict[str, Any]) -> spaces.Box:
    """The float32 action Box a checkpoint was written for."""
    return spaces.Box(
        np.asarray(state["action_low"], dtype=np.float32),
        np.asarray(state["action_high"], dtype=np.float32),
        dtype=np.float32,
    )


def check_loadable(state: Any, dims: dict[str, Any], config: Any, strict_config: bool) -> None:
    """ValueError unless `state` is a checkpoint whose "obs_dim", "critic_obs_dim", "action_low" and
    "action_high" equal `dims`' and (with `strict_config`) whose config equals the dataclass
    `config` field by field; the message names every field that differs."""
    if not is_checkpoint(state):
        raise ValueError(f"PPO.load_state_dict: not a PPO checkpoint (expected format {CHECKPOINT_FORMAT!r})")
    for key, mine in dims.items():
        if state[key] != mine:
            raise ValueError(f"PPO.load_state_dict: the checkpoint's {key} is {state[key]}, this PPO's is {mine}")
    saved = saved_config(state)
    mine = dataclasses.asdict(config)
    diff = sorted(k for k in set(saved) | set(mine) if saved.get(k) != mine.get(k))
    if diff and strict_config:
        raise ValueError(
            "PPO.load_state_dict: the checkpoint's config differs from this PPO's in "
            + ", ".join(f"{k} (checkpoint {saved.get(k)!r}, here {mine.get(k)!r})" for k in diff)
            + "; build the PPO with the checkpoint's config (PPO.from_checkpoint) or pass "
            "strict_config=False"
        )


def write_checkpoint(path: str | os.PathLike[str], state: dict[str, Any]) -> None:
    """Write `state` to `path` atomically (OutputPathError for an unusable path)."""
    save_tensors(check_output_file(path, "PPO checkpoint"), state)


def read_checkpoint(path: str | os.PathLike[str], check: bool = True) -> Any:
    """The data of the checkpoint file at `path` (as data only). FileNotFoundError without a file,
    FileFormatError naming it when it is not a torch file or (with `check`) not in this format."""
    state = load_tensors(path, CHECKPOINT_WHAT)
    if check and not is_checkpoint(state):
        raise FileFormatError(f"{path}: not a {CHECKPOINT_WHAT}")
    return state
