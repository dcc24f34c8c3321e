"""The Python API (``gpl_dist.app.policy``) on the report's archived multi-room policy, and the
pictures that mark where an attempt solved its task."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from gpl_dist.app.policy import load_policy
from gpl_dist.app.rendering import SOLVED_RGB, replay_attempt, step_caption, still_frame

ARCHIVED = Path(__file__).resolve().parents[1] / "docs" / "paper-report" / "runs" / "multiroom-gpl" / "seed0"


@pytest.fixture(scope="module")
def policy(tmp_path_factory):
    run = tmp_path_factory.mktemp("api") / "seed0"
    shutil.copytree(ARCHIVED, run)
    return load_policy(run)


def test_attempts_from_corrections_are_meta_tests_and_replay_exactly(policy):
    by_oracle = policy.attempts(263, seed=1, num_corrections=4)  # the README's GIF: solved after 2 corrections
    assert len(by_oracle) >= 2 and by_oracle[-1].success and not by_oracle[0].success
    said = [a.correction for a in by_oracle[:-1]]
    assert said[0] == policy.oracle_correction(by_oracle[0], seed=1)
    typed = policy.attempts(263, said, seed=1)  # a person typing the oracle's words gets the same attempts
    assert [a.actions.tolist() for a in typed] == [a.actions.tolist() for a in by_oracle]
    assert [a.completion for a in typed] == [a.completion for a in by_oracle]
    with pytest.raises(Exception, match="outside"):
        policy.attempts(99999, [])


def test_the_step_an_attempt_solved_its_task_is_marked_not_sticky(policy):
    solved = policy.attempts(263, seed=1, num_corrections=4)[-1]
    at = policy.solved_at(solved)
    assert at is not None and 1 <= at <= solved.length
    replay = replay_attempt("multiroom", 263, solved.actions, solved.seed)
    assert len(policy.frames(solved)) == solved.length + 1 == len(replay.frames)
    assert "solved" not in step_caption(at - 1, solved.length, replay)
    assert f"solved at step {at}" in step_caption(at, solved.length, replay)
    still = still_frame(replay)
    assert still.shape == replay.frames[-1].shape and not np.array_equal(still, replay.frames[-1])  # the path drawn
    assert (np.abs(still.astype(int) - SOLVED_RGB).sum(axis=2) == 0).any()  # the ring where it was solved
    unsolved = policy.attempts(263, seed=1, num_corrections=4)[0]
    assert policy.solved_at(unsolved) is None
