"""The learner as a Ray actor on a GPU node, for a run whose driver's node has no GPU.

``placement`` decides where the learner runs (pure logic, tested on any machine); ``RemoteLearner``
is the driver's handle on a ``LearnerActor`` placed with ``num_gpus=1``. The handle keeps a CPU
replica of the model, the Adam state and the batch generator's state: every round it sends them
with the training view (numpy, through Ray's object store), the actor trains and sends the new
state back. The driver therefore checkpoints, resumes and hands weights to the rollout actors
(one ``ray.put`` per round, as always) exactly as with a local learner, and a restarted actor
retries the round from the state sent with it. That driver side, ``ShippedStateLearner``, is
shared with the Ray Train learners (``learner.ray_train``). This module imports Ray: it is only
loaded by a run that uses a cluster.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from gpl_dist.config import ConfigError, TrainingConfig
from gpl_dist.records import LearnerState

DRIVER, GPU_ACTOR = "driver", "gpu-actor"
#: how long the driver waits for the learner's actor to be placed on a GPU
GPU_WAIT_S = 600


def placement(device: str, driver_has_cuda: bool, cluster_gpus: float) -> str:
    """Where the learner runs: ``DRIVER`` (this process, plus its data-parallel helpers) or
    ``GPU_ACTOR`` (a Ray actor holding one GPU elsewhere in the cluster).

    ``cpu`` always trains in the driver; ``cuda`` and ``auto`` use the driver's own GPU when it has
    one, else a cluster GPU; ``cuda`` with no GPU anywhere is a ``ConfigError``, ``auto`` then
    falls back to the CPU.
    """
    if device == "cpu" or driver_has_cuda:
        return DRIVER
    if cluster_gpus >= 1:
        return GPU_ACTOR
    if device == "cuda":
        raise ConfigError("training.device is cuda, but neither this machine nor the Ray cluster has a GPU "
                          "(use training.device=auto or cpu)")
    return DRIVER


def cluster_gpus() -> float:
    """GPUs in the Ray cluster this process is connected to."""
    import ray
    return float(ray.cluster_resources().get("GPU", 0.0))


def _cpu(value):
    """``value`` (a state dict, possibly nested) with every tensor on the CPU."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().clone()  # a view of the flat parameters would pickle all of them
    if isinstance(value, dict):
        return {k: _cpu(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_cpu(v) for v in value]
    return value


def train_from_state(learner, state: LearnerState, view) -> tuple[Any, LearnerState]:
    """Train one round on ``learner`` from the driver's ``state``; return the round's statistics
    and the new state, on the CPU. A round depends only on its inputs, so retrying it after a
    failure is safe."""
    learner.load_state(state)
    stats = learner.train_round(view)
    new = learner.state()
    return stats, LearnerState(_cpu(dict(new.model)), _cpu(dict(new.optimizer or {})) or None, new.generator.clone())


class LearnerActorImpl:
    """What runs inside the actor: a learner that trains from a state and returns the new one."""

    def __init__(self, model: nn.Module, cfg: TrainingConfig, seed: int):
        from learner.parallel import make_learner

        self.learner = make_learner(model, cfg, seed)

    def train_round(self, state: LearnerState, view):
        return train_from_state(self.learner, state, view)

    def device(self) -> str:
        return str(next(self.learner.model.parameters()).device)


class ShippedStateLearner:
    """A learner that trains elsewhere from state the driver holds; implements
    ``gpl_dist.roles.Learner`` (its ``state`` / ``load_state`` are the replica's).

    The driver keeps a CPU replica of the model, the Adam state and the batch generator's state;
    every round ``_train_elsewhere`` sends them with the training view and returns the new ones.
    The driver therefore checkpoints, resumes and hands weights to the rollout actors exactly as
    with a local learner.
    """

    def __init__(self, model: nn.Module, cfg: TrainingConfig, seed: int = 0):
        self.model = model
        self.cfg = cfg
        self._optimizer: dict | None = None
        self._generator = torch.Generator().manual_seed(seed)

    def _train_elsewhere(self, state: LearnerState, view):
        """``train_from_state`` run wherever this learner trains; returns its result."""
        raise NotImplementedError

    def state(self) -> LearnerState:
        return LearnerState(self.model.state_dict(), self._optimizer, self._generator.get_state())

    def load_state(self, state: LearnerState) -> None:
        self.model.load_state_dict(dict(state.model))
        self._optimizer = None if state.optimizer is None else dict(state.optimizer)
        self._generator.set_state(state.generator)

    def weights(self) -> dict:
        from gpl_dist.models.build import state_dict_to_numpy
        return state_dict_to_numpy(self.model)

    def train_round(self, view, on_epoch=None):
        stats, new = self._train_elsewhere(self.state(), view)
        self.load_state(new)
        if on_epoch is not None:
            on_epoch(self.cfg.num_epochs_per_round - 1, stats.loss, stats.accuracy)
        return stats

    def close(self) -> None:
        """Release what trains elsewhere."""


class RemoteLearner(ShippedStateLearner):
    """The driver's handle on a ``LearnerActorImpl`` actor holding a GPU (``ShippedStateLearner``)."""

    def __init__(self, model: nn.Module, cfg: TrainingConfig, seed: int = 0, num_gpus: float = 1.0):
        import ray

        super().__init__(model, cfg, seed)
        # num_cpus=0: the rollout actors hold the CPUs (platform notes: the deadlock trap)
        # a round depends only on the state sent with it: a restarted actor retries it safely
        actor = ray.remote(num_cpus=0, num_gpus=num_gpus, max_restarts=1, max_task_retries=1)(LearnerActorImpl)
        self._actor: Any = actor.remote(model, cfg, seed)  # type: ignore[attr-defined]  # an ActorClass
        if num_gpus:
            self._check_on_gpu()

    def _check_on_gpu(self) -> None:
        """Fail in one line when the actor got no GPU in time or its torch cannot use one."""
        import ray
        from ray.exceptions import GetTimeoutError

        try:
            device = ray.get(self._actor.device.remote(), timeout=GPU_WAIT_S)
        except GetTimeoutError:
            ray.kill(self._actor)
            raise ConfigError(f"the learner's Ray actor got no free GPU within {GPU_WAIT_S} s (every GPU of the "
                              "cluster is taken?); use training.device=cpu or free one") from None
        if not device.startswith("cuda"):
            ray.kill(self._actor)
            raise ConfigError(f"the learner's Ray actor holds a GPU but its torch trains on {device} (a CPU-only "
                              "torch build on the GPU node?); install a CUDA torch there or use training.device=cpu")

    def device(self) -> str:
        import ray
        return ray.get(self._actor.device.remote())

    def _train_elsewhere(self, state, view):
        import ray
        return ray.get(self._actor.train_round.remote(state, view))

    def close(self) -> None:
        import ray
        ray.kill(self._actor)
