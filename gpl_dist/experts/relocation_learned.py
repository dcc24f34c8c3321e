"""Learned expert for robotic object relocation: an MLP policy given the exact target, as the authors'.

Why: the paper's experts were policies learned per task with PPO (small MLPs), whose action
distributions are smooth functions of the state. The scripted planner (``gpl_dist.experts.relocation``)
is about as good a policy, but its bang-bang, grid-planned choices are hard to imitate, even with
the exact target given (``docs/history.md`` has the figures).

What: one network for all tasks, ``pi(a | obs, target, block)``: the 28-d observation, the task's
exact target (x, y) and the goal block's one-hot (the authors' full-information inputs), through
an input normalisation and an MLP 256 x 3 (ReLU) to 4 action logits. A family of per-task
experts in one function. Trained in two steps (``learner.relocation_expert_training``;
``scripts/train_relocation_expert.py`` runs them):

1. DAgger on the scripted expert's soft labels, 14 rounds over 250 training tasks;
2. PPO with the paper's dense reward ``-(|arm - block| + 5 |block - target|)`` over all 750
   training tasks, starting from step 1's weights (clip 0.1, GAE, a critic learned from scratch
   with the policy frozen for its first iterations, an early stop on the policy's KL).

The packaged weights are those after 600 PPO iterations; ``research/relocation_expert.py
--expert learned`` measures their completion (``docs/history.md`` has the figures).

Labels: ``label(env)`` is ``(argmax action, softmax distribution)``, float32 ``(4,)``; the
learner fits the distribution, as the authors fitted their PPO experts'. ``label_batch(envs)``
labels many envs with one forward (the rollout loop's path: one batch-1 forward per env and step
was half of a relocation collection's time). Stateless and deterministic: the same state gives
the same label, bit for bit, whichever batch it is labelled in and by either method (both run
``batch_probs``, which pads every batch to a multiple of ``ROW_BLOCK`` rows: OpenBLAS computes
the rows of a matrix product's last partial block of rows with other kernels, whose sums differ
in the last bits). Weights live in ``gpl_dist/assets/relocation_learned_expert.npz`` (plain
arrays, loaded without pickle).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from importlib import resources
from typing import Any

import numpy as np

from gpl_dist.envs.relocation_core import FIXED_XY

WEIGHTS = "relocation_learned_expert.npz"
#: array names in the weights file: input normalisation, then (weight, bias) of each linear layer
NORM_KEYS = ("norm_mean", "norm_var", "norm_weight", "norm_bias")
NUM_LAYERS = 4
NORM_EPS = 1e-5
#: ``batch_probs`` runs its matrix products on a multiple of this many rows (see the module
#: docstring): a multiple of the row blocks of OpenBLAS's double-precision kernels (4 to 16)
ROW_BLOCK = 16


@lru_cache(maxsize=None)
def load_weights() -> dict[str, np.ndarray]:
    """The packaged weights as float64 arrays (float64: a batch-1 forward is dominated by call
    overhead, and it keeps labels identical across numpy builds' float32 summation orders)."""
    with resources.files("gpl_dist").joinpath("assets", WEIGHTS).open("rb") as fh:
        raw = np.load(fh, allow_pickle=False)
        weights = {k: raw[k].astype(np.float64) for k in raw.files}
    missing = [k for k in (*NORM_KEYS, *(f"w{i}" for i in range(NUM_LAYERS)), *(f"b{i}" for i in range(NUM_LAYERS)))
               if k not in weights]
    if missing:
        raise ValueError(f"{WEIGHTS} lacks arrays {missing}")
    return weights


#: Values of the network's input: the 28-d observation, the target (x, y) and the goal block's one-hot.
INPUT_DIM = 33


def input_rows(observations: Any, targets: Any, blocks: Sequence[int], dtype: Any = np.float64) -> np.ndarray:
    """``(n, INPUT_DIM)`` of ``dtype``: each row the observation ``(28,)`` in the env's layout (qpos 9,
    fixed blocks 10, qvel 9), the task's target xy and its goal block's one-hot; the one builder of
    the expert's input, for the packaged expert and its training alike."""
    n = len(blocks)
    x = np.zeros((n, INPUT_DIM), dtype)
    x[:, 0:28] = observations
    x[:, 28:30] = targets
    x[np.arange(n), [30 + int(b) for b in blocks]] = 1.0
    return x


def policy_inputs_batch(envs: Sequence[Any]) -> np.ndarray:
    """``(n, 33)`` float64 ``input_rows`` of each env's state: qpos, the fixed blocks and qvel read
    in float64 from the simulator (not the env's float32 observation), its task's target and block."""
    es = [getattr(env, "unwrapped", env) for env in envs]
    observations = np.empty((len(es), 28))
    observations[:, 0:9] = [e.data.qpos for e in es]
    observations[:, 9:19] = FIXED_XY.reshape(-1)
    observations[:, 19:28] = [e.data.qvel for e in es]
    return input_rows(observations, [e.task.target for e in es], [e.task.block for e in es])


def policy_inputs(env: Any) -> np.ndarray:
    """``(33,)`` float64: ``policy_inputs_batch`` of the one env."""
    return policy_inputs_batch([env])[0]


def batch_probs(weights: dict[str, np.ndarray], x: np.ndarray) -> np.ndarray:
    """``action_probs`` of ``x`` ``(n, 33)``, each row the same bits whatever ``n`` and its place
    in the batch: the products run on ``x`` padded with zero rows to a multiple of ``ROW_BLOCK``
    (``tests/test_relocation_learned_expert.py`` checks the invariance on this machine's BLAS)."""
    n = x.shape[0]
    padded = -(-max(n, 1) // ROW_BLOCK) * ROW_BLOCK
    if padded != n:
        x = np.concatenate([x, np.zeros((padded - n, x.shape[1]))])
    return action_probs(weights, x)[:n]


def action_probs(weights: dict[str, np.ndarray], x: np.ndarray) -> np.ndarray:
    """Softmax of the network's logits for inputs ``x`` ``(..., 33)`` (the last bits depend on
    the batch's shape; ``batch_probs`` does not)."""
    h = (x - weights["norm_mean"]) / np.sqrt(weights["norm_var"] + NORM_EPS) * weights["norm_weight"] + weights["norm_bias"]
    for i in range(NUM_LAYERS):
        h = h @ weights[f"w{i}"].T + weights[f"b{i}"]
        if i < NUM_LAYERS - 1:
            h = np.maximum(h, 0.0)
    h = h - h.max(axis=-1, keepdims=True)
    p = np.exp(h)
    return p / p.sum(axis=-1, keepdims=True)


class LearnedRelocationExpert:
    """``act(env)`` / ``label(env)`` / ``label_batch(envs)`` from the packaged network (see the
    module docstring); a ``gpl_dist.roles.BatchExpert``."""

    soft_labels = True

    def __init__(self):
        self._weights = load_weights()

    def label_batch(self, envs: Sequence[Any]) -> tuple[np.ndarray, np.ndarray]:
        probs = batch_probs(self._weights, policy_inputs_batch(envs))
        return probs.argmax(axis=1).astype(np.int64), probs.astype(np.float32)

    def label(self, env: Any) -> tuple[int, np.ndarray]:
        actions, probs = self.label_batch([env])
        return int(actions[0]), probs[0]

    def act(self, env: Any) -> int:
        return self.label(env)[0]
