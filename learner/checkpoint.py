"""Atomic checkpoints: model, optimiser, round, RNG states and the resolved config.

Written to a temporary name and renamed, so a driver killed mid-write leaves the previous
checkpoint intact. Loaded with ``torch.load(..., weights_only=True)``: a checkpoint can hold
tensors and plain Python values only, never code.
"""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gpl_dist.errors import CheckpointError
from gpl_dist.records import LearnerState
from gpl_dist.roles import Learner as LearnerRole

LATEST = "latest.pt"


@dataclass(frozen=True)
class Checkpoint:
    """A loaded checkpoint.

    Attributes:
        round_index: last round whose training finished.
        policy_version: version number of the weights.
        model_state: the model's state dict.
        optimizer_state: the Adam state dict.
        rng_state: torch and numpy global RNG states and the learner's batch generator.
        config: the resolved run config as a plain dict.
        history: per-round metrics so far.
        run_id: the identity of the run that trained it (``learner.identity``); None where the
            file records none (``load_checkpoint``).
    """

    round_index: int
    policy_version: int
    model_state: dict
    optimizer_state: dict
    rng_state: dict
    config: dict
    history: list
    run_id: str | None = None


def capture_rng(generator_state: torch.Tensor) -> dict:
    """The torch and numpy global RNG states and the batch generator's (``LearnerState.generator``),
    as tensors and plain values."""
    np_state: tuple = np.random.get_state(legacy=True)  # type: ignore[assignment]  # legacy=True is the tuple form
    return {
        "torch": torch.get_rng_state(),
        "generator": generator_state,
        "numpy": {"key": torch.from_numpy(np_state[1].astype(np.int64)), "pos": int(np_state[2]),
                  "has_gauss": int(np_state[3]), "cached_gaussian": float(np_state[4])},
    }


def restore_rng(state: dict) -> None:
    """Restore the global RNG states ``capture_rng`` captured (the batch generator's goes back
    with the learner's state: ``load_learner_state``)."""
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state(("MT19937", n["key"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached_gaussian"]))


def save_checkpoint(directory: str | os.PathLike, ckpt: Checkpoint, keep_round_copy: bool = True) -> Path:
    """Write ``ckpt`` atomically as ``latest.pt`` (and ``round-R.pt``); returns the path."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    payload: dict[str, Any] = {
        "round_index": ckpt.round_index, "policy_version": ckpt.policy_version,
        "model_state": ckpt.model_state, "optimizer_state": ckpt.optimizer_state,
        "rng_state": ckpt.rng_state, "config": ckpt.config, "history": ckpt.history,
    }
    if ckpt.run_id is not None:
        payload["run_id"] = ckpt.run_id
    tmp = d / f".{LATEST}.tmp-{os.getpid()}"
    torch.save(payload, tmp)
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    if keep_round_copy:
        round_path = d / f"round-{ckpt.round_index:06d}.pt"
        round_tmp = d / f".{round_path.name}.tmp-{os.getpid()}"
        shutil.copyfile(tmp, round_tmp)
        os.replace(round_tmp, round_path)
    final = d / LATEST
    os.replace(tmp, final)
    return final


def load_checkpoint(path: str | os.PathLike) -> Checkpoint:
    """Load a checkpoint file or the latest one in a directory (``weights_only=True``).

    The one place a checkpoint of any era is read; it returns the current shape. The eras:

    - one Adam state per parameter tensor, no ``run_id`` (saved before the parameters were
      flattened): the moments are concatenated into the flat parameter's (``_flat_moments``);
    - the flat moments, no ``run_id`` (saved before run identities): ``run_id`` None, "not recorded";
    - the current: the flat moments and ``run_id``.

    Raises ``CheckpointError`` naming the file when it is missing, is not a torch file of plain
    values and tensors (a pickle of code is refused, never run), or lacks a checkpoint's fields.
    """
    p = Path(path)
    if p.is_dir():
        p = p / LATEST
    if not p.is_file():
        raise CheckpointError(f"no checkpoint at {p}")
    try:
        raw = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - torch raises many types for a bad file; its text suggests unsafe loading
        raise CheckpointError(f"{p} is not a readable gpl-dist checkpoint ({type(err).__name__})") from None
    fields = {f.name for f in dataclasses.fields(Checkpoint)}
    if not isinstance(raw, dict) or set(raw) not in (fields, fields - {"run_id"}):  # without: the era with no run id
        have = sorted(map(str, raw))[:20] if isinstance(raw, dict) else type(raw).__name__
        raise CheckpointError(f"{p} is not a gpl-dist checkpoint (holds {have})")
    if not isinstance(raw.get("run_id", ""), str):
        raise CheckpointError(f"{p} is not a gpl-dist checkpoint (its run_id is not a string)")
    return Checkpoint(**{**raw, "optimizer_state": _flat_moments(raw["optimizer_state"], raw["model_state"], p)})


#: The persistent buffers of the models' state dicts (BatchNorm's): every other entry is a parameter.
_BUFFERS = ("running_mean", "running_var", "num_batches_tracked")


def _flat_moments(state: dict, model_state: dict, path: Path) -> dict:
    """``state`` with Adam's moments over the one flat parameter (``learner.trainer.flatten_parameters``):
    per-tensor moments (one entry per parameter, in the model's parameter order: the state dict's
    entries less its buffers, a tensor that two modules share once) are concatenated, a parameter
    without any (it never had a gradient) taking zeros, and ``step`` is the largest
    step of any tensor (exact when every tensor took the same steps, as in gpl-dist's rounds).
    Flat or empty state is returned as it is."""
    groups = state.get("param_groups") if isinstance(state, dict) else None
    if not groups or len(groups[0]["params"]) <= 1:
        return state
    params = groups[0]["params"]
    tensors = {(t.untyped_storage().data_ptr(), t.storage_offset(), tuple(t.shape)): t
               for k, t in model_state.items() if k.rsplit(".", 1)[-1] not in _BUFFERS}
    sizes = [t.numel() for t in tensors.values()]
    per = [state["state"].get(i) for i in params]
    if len(sizes) != len(params) or any(x is not None and x["exp_avg"].numel() != n for x, n in zip(per, sizes)):
        raise CheckpointError(f"{path}: its Adam moments do not fit its model's parameters")
    flat = {key: torch.cat([x[key].reshape(-1) if x is not None else torch.zeros(n) for x, n in zip(per, sizes)])
            for key in ("exp_avg", "exp_avg_sq")}
    flat["step"] = max((x["step"] for x in per if x is not None), default=torch.tensor(0.0)).clone()
    return {"state": {0: flat} if any(x is not None for x in per) else {}, "param_groups": [{**groups[0], "params": [0]}]}


def check_checkpoint_run(ckpt: Checkpoint, path: str | os.PathLike, run_id: str, run_dir: str | os.PathLike) -> None:
    """``CheckpointError`` naming both runs when ``ckpt`` was trained by another run than ``run_id``
    (a checkpoint that records no run id is taken as the run's own: ``load_checkpoint`` reads that
    era's files with ``run_id`` None)."""
    if ckpt.run_id is not None and ckpt.run_id != run_id:
        raise CheckpointError(f"{path} is a checkpoint of run {ckpt.run_id[:64]}, not of {run_dir} (run {run_id[:64]})")


def rounds_trained(run_dir: str | os.PathLike) -> int:
    """How many DAgger rounds a run has trained: its latest checkpoint's round + 1, 0 without one."""
    latest = Path(run_dir) / "checkpoints" / LATEST
    return load_checkpoint(latest).round_index + 1 if latest.is_file() else 0


def learner_state(ckpt: Checkpoint) -> LearnerState:
    """The learner's state that ``ckpt`` holds (an empty optimizer state: none yet)."""
    optimizer = ckpt.optimizer_state if ckpt.optimizer_state and ckpt.optimizer_state.get("param_groups") else None
    return LearnerState(ckpt.model_state, optimizer, ckpt.rng_state["generator"])


def load_learner_state(learner: LearnerRole, ckpt: Checkpoint, source: str | os.PathLike) -> None:
    """Continue ``learner`` from ``ckpt``; ``CheckpointError`` when its weights belong to another architecture."""
    try:
        learner.load_state(learner_state(ckpt))
    except (RuntimeError, KeyError, TypeError) as err:
        first = str(err).strip().splitlines()[0][:200]
        raise CheckpointError(f"{source} does not fit this run's model (another variant or size?): {first}") from None


def load_model_state(model: torch.nn.Module, ckpt: Checkpoint, source: str | os.PathLike) -> None:
    """Load ``ckpt``'s weights into ``model``; ``CheckpointError`` when they belong to another architecture."""
    try:
        model.load_state_dict(ckpt.model_state)
    except (RuntimeError, KeyError, TypeError) as err:
        first = str(err).strip().splitlines()[0][:200]
        raise CheckpointError(f"{source} does not fit this run's model (another variant or size?): {first}") from None


#: A temporary file a gpl-dist process writes beside its final name: ``.<name>.tmp-<pid>[-<thread>][.<suffix>]``
#: (``gpl_dist.atomic.temporary_name``).
_TEMPORARY = re.compile(r"^\.[^/]+\.tmp-(\d+)(?:-\d+)?(?:\.\w+)?$")


def dead_temporaries(run_dir: str | os.PathLike) -> list[Path]:
    """Temporary files in ``run_dir`` and its ``checkpoints/`` whose writer (the pid in the name)
    no longer runs on this host: what a process killed mid-write (a full disk, a signal) left."""
    out = []
    for folder in (Path(run_dir), Path(run_dir) / "checkpoints"):
        for path in sorted(folder.glob(".*.tmp-*")) if folder.is_dir() else []:
            m = _TEMPORARY.match(path.name)
            if m and path.is_file() and not _running(int(m.group(1))):
                out.append(path)
    return out


def _running(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True  # another user's process (or an absurd number): leave its files alone
    return True
