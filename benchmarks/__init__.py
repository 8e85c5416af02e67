"""Benchmarks of sb3-trpo-plus and grasp_envs, each run from the repository root as ``python -m benchmarks.<name>``.

- ``convergence``: the convergence study's command line (``run``, ``job``, ``reevaluate``, ``report``, ``agents``);
  its configuration is ``study.yml`` (read by ``study``), its envs and models come from ``builders``, its jobs from
  ``runner``, its evaluations from ``protocol``, its files from ``runs``, its tables and figures from ``report``;
- ``speed``, ``scaling``, ``env_speed``: time per update and per env step;
- ``grasper_probe``, ``grasper_reward``, ``trpo_divergence``, ``update_kl``, ``warm_start``, ``warm_start_share``,
  ``multistep``: diagnoses and probes of the study's runs.
"""
