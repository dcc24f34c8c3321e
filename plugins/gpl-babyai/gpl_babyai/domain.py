"""The BabyAI domain of gpl-dist: ``DOMAIN``, declared under the ``gpl_dist.domains`` entry points.

Importing this module is light (no minigrid, no torch): the env, the expert and the correction
oracle are imported on first use. What each part is:

- tasks: ``gpl_babyai.tasks`` (a (level, seed) table in ``gpl_babyai/splits/babyai.json``,
  written by ``gpl_babyai.generate``), 9 trained levels and 2 held-out ones;
- env: ``gpl_babyai.env.BabyAIEnv`` (BabyAI's 7x7x3 view, minigrid's 7 actions, the level's
  mission as instruction, BabyAI's success, completion over the bot's subgoals);
- expert: ``gpl_babyai.expert.BotExpert`` (minigrid's BabyAI bot, replanning after the policy's
  actions);
- corrections: ``gpl_babyai.corrections`` (subgoal, directional, all, retry).
"""

from __future__ import annotations

from gpl_babyai import tasks as task_table
from gpl_dist.language import Vocabulary
from gpl_dist.models.sizes import Sizes
from gpl_dist.roles import DomainSpec, lazy

#: Actions per attempt (``gpl_babyai.env.STEPS``): every task's bot solves it from its start in at
#: most 96 steps (``gpl_babyai.generate.BOT_STEP_CAP``); the rest is a learner's margin.
STEPS = 128
#: The correction module reads every 32nd state of an earlier attempt: 4 states, as multi-room's 25 of 100.
TRAJECTORY_STRIDE = 32

#: Every word of BabyAI's grammar (minigrid's ``verifier``: the four clauses, descriptions with
#: article, colour, type and location, "and", "then", "after you") and of the corrections. Token
#: ids are ``2 + index``: append new words at the end, never reorder.
WORDS = (
    "go", "to", "pick", "up", "open", "put", "next",
    "the", "a",
    "red", "green", "blue", "purple", "yellow", "grey",
    "door", "key", "ball", "box", "object",
    "in", "front", "of", "you", "behind", "on", "your", "left", "right",
    "and", "then", "after",
    "is", "are", "not", "done",
)
#: Missions of the task set have at most 40 words (``generate.MAX_WORDS``); the full-information
#: text (the bot's subgoals joined by "then") is cut there too.
VOCABULARY = Vocabulary(words=WORDS, max_tokens=40)

CORRECTION_KINDS = ("default", "subgoal", "directional", "all", "retry")

#: Layer sizes: wider than multi-room's where BabyAI asks more. The state encoder reads 20 one-hot
#: codes per cell (11 types, 6 colours, 3 door states) and must find the object the instruction
#: names among up to 18 distractors: 16 filters and a 64-wide MLP (multi-room: 8 and 32). The
#: instruction is a sentence of up to 40 words of a compositional grammar (colour x type x
#: location x clause x sequence), not multi-room's one template: 16 word filters and a 64-wide
#: encoding (multi-room: 4 and 32). Corrections name one subgoal of ~6 words: a 16-wide encoding
#: (multi-room: 4). The policy MLP combines them: 128 wide (multi-room: 64). The trajectory
#: encoder keeps multi-room's shape with 8 filters.
MODEL_SIZES = Sizes(
    state_channels=(16, 16), state_mlp=(64, 64),
    traj_state_channels=(8, 8), traj_state_mlp=(32, 32), traj_conv=8, traj_mlp=(32, 16),
    text_conv=16, correction_mlp=(32, 16), instruction_mlp=(64, 64),
    pair_mlp=(32, 32), pair_final_relu=True, policy_mlp=(128, 128),
)

_SPLITS = task_table.splits()

DOMAIN = DomainSpec(
    name="babyai",
    env_id="gpl-babyai/BabyAI-v0",
    num_tasks=task_table.num_tasks(),
    obs_shape=(7, 7, 3),
    obs_dtype="uint8",
    num_actions=7,
    steps_per_attempt=STEPS,
    trajectory_stride=TRAJECTORY_STRIDE,
    vocabulary=VOCABULARY,
    make_env=lazy("gpl_babyai.env:make_env"),
    split_names=tuple(_SPLITS),
    splits=_SPLITS,
    valid_splits={"train": "valid"},
    experts={"bot": lazy("gpl_babyai.expert:BotExpert")},
    correction_kinds=CORRECTION_KINDS,
    make_corrector=lazy("gpl_babyai.corrections:make_corrector"),
    correction_phrasings=lazy("gpl_babyai.corrections:phrasings"),
    model_sizes=MODEL_SIZES,
    paper_completion={},  # the paper has no BabyAI figures
    obs_categories=(11, 6, 3),
)
