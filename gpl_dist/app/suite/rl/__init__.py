"""The paper's sample-complexity comparison: RL per test task against GPL and GPR (a suite file's
``rl`` section; its results under ``OUT/rl/``).

- ``per_task``: PPO on one task (``rl-scratch``, ``rl-finetune``), its job and its curve;
- ``plan``: the suite file's ``rl`` section and the jobs it names;
- ``jobs``: ``gpl-dist suite rl``, each result written as it finishes; ``cluster``: the jobs as Ray tasks;
- ``report``: the report's sample-complexity section and figure.
"""
