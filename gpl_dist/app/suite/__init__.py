"""Experiment suites: the paper's experiments as overlays of the shipped configs, run, resumed,
reported and archived.

- ``spec``: the suite file (``load_suite``), its entries and evaluations; ``rl_plan``: its ``rl`` section;
- ``runs``: one run's record, state and execution; ``runner``: ``gpl-dist suite run``;
  ``cluster``: the runs as Ray tasks;
- ``rl_jobs``: ``gpl-dist suite rl``; ``rl_cluster``: those jobs as Ray tasks; ``rl_report``: their figure;
- ``report``: ``gpl-dist suite report``; ``archive``: ``suite restore``; ``cost``: ``suite status``'s predictions.
"""
