"""Experiment suites: the paper's experiments as overlays of the shipped configs, run, resumed,
reported and archived.

- ``spec``: the suite file (``load_suite``), its entries and evaluations;
- ``one_run``: one run's record (``suite-run.json``), state and execution; ``every_run``: ``gpl-dist
  suite run``, every run of a plan; ``cluster``: the runs as Ray tasks; ``provenance``: the code's commit;
- ``run_facts``: what a run's own files say (setup, health, budget, learning curve, swap control);
- ``records``: the curve and instruction-swap files; ``curves``, ``swap``: ``suite curves`` and ``suite swap``;
- ``rl``: the RL comparison (``gpl-dist suite rl``, its plan, jobs, Ray tasks and figure);
- ``report``: ``gpl-dist suite report``; ``archive``: ``suite restore``; ``status``, ``cost``: ``suite status``.
"""
