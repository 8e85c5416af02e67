"""The application: the ``trpo-plus`` command (:mod:`~sb3_trpo_plus.application.cli`) over rl-zoo3
(:mod:`~sb3_trpo_plus.application.zoo`, :mod:`~sb3_trpo_plus.application.experiment`), the recipes
(:mod:`~sb3_trpo_plus.application.recipes`: ``make_model``), and trained runs: where they are
(:mod:`~sb3_trpo_plus.application.run_folders`), reading their files as data
(:mod:`~sb3_trpo_plus.application.run_files`), loading (:mod:`~sb3_trpo_plus.application.agents`), evaluating
(:mod:`~sb3_trpo_plus.application.evaluation`), plotting (:mod:`~sb3_trpo_plus.application.plotting`) and the
callbacks of a run (:mod:`~sb3_trpo_plus.application.callbacks`)."""
