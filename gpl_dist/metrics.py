"""The paper's headline metric: mean completion after 0..K corrections."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from gpl_dist.records import Attempt

#: What the round line means, printed once above the first one (and in ``gpl-dist train --help``).
ROUND_LINE_LEGEND = (
    "each round prints one line: the tuples collected (states labelled by the expert) and the seconds it took; "
    "'buffer' the tuples trained on; 'train' the seconds, loss and accuracy of the policy against the expert's "
    "labels; 'corr-spread' how much the correction module's output differs between attempts (0: it is dead; "
    "absent when the variant reads no corrections or the round's last batch held fewer than two corrected attempts); "
    "'dead i c t p' the hidden units never positive (ReLU or LeakyReLU), of all, in the instruction, correction, "
    "trajectory and pair encoders; 'cK' the mean completion on the training tasks after K corrections "
    "(c0: the instruction alone)")


def completion_by_corrections(task_ids: np.ndarray, attempt_index: np.ndarray, completion: np.ndarray,
                              max_attempts: int) -> np.ndarray:
    """Mean over tasks of the completion of attempt ``k`` (after ``k`` corrections), ``k < max_attempts``.

    One entry per attempt: ``task_ids``, ``attempt_index`` and ``completion`` are parallel arrays.
    A task that stopped early (it was solved, so it was not rolled out again) carries its last
    completion forward to every later ``k``.
    """
    task_ids = np.asarray(task_ids)
    if task_ids.size == 0:
        return np.zeros(max_attempts)
    uniq, inv = np.unique(task_ids, return_inverse=True)
    table = np.full((uniq.size, max_attempts), np.nan)
    table[inv, np.minimum(np.asarray(attempt_index), max_attempts - 1)] = np.asarray(completion, dtype=float)
    for col in range(1, max_attempts):
        missing = np.isnan(table[:, col])
        table[missing, col] = table[missing, col - 1]
    return np.nan_to_num(table).mean(axis=0)


def completion_by_attempt(attempts: Sequence[Attempt], max_attempts: int) -> np.ndarray:
    """Mean completion after 0..max_attempts-1 corrections over the tasks in ``attempts``."""
    return completion_by_corrections(np.array([a.task_id for a in attempts]), np.array([a.attempt_index for a in attempts]),
                                     np.array([a.completion for a in attempts]), max_attempts)
