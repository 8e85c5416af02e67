"""The algorithm: :class:`~sb3_trpo_plus.algorithm.trpo_plus.TRPOPlus` and what it needs to learn from any SB3
``VecEnv``.

* collecting: :mod:`~sb3_trpo_plus.algorithm.segment` (SB3's ``collect_rollouts`` as one segment),
  :mod:`~sb3_trpo_plus.algorithm.collection` (the learner's half), :mod:`~sb3_trpo_plus.algorithm.segment_pool` (the
  face of a pool of rollout workers the learner collects from), :mod:`~sb3_trpo_plus.algorithm.normalization`
  (``VecNormalize`` statistics as data);
* updating: :mod:`~sb3_trpo_plus.algorithm.update` (the natural-gradient step),
  :mod:`~sb3_trpo_plus.algorithm.natural_gradient`, :mod:`~sb3_trpo_plus.algorithm.critic`,
  :mod:`~sb3_trpo_plus.algorithm.baselines`;
* sample reuse: :mod:`~sb3_trpo_plus.algorithm.generalized`, :mod:`~sb3_trpo_plus.algorithm.reuse`,
  :mod:`~sb3_trpo_plus.algorithm.replay`;
* the constructor's argument rules: :mod:`~sb3_trpo_plus.algorithm.hyperparameters`.

Nothing here imports :mod:`sb3_trpo_plus.rollouts` or :mod:`sb3_trpo_plus.application`.
"""

from sb3_trpo_plus.algorithm.trpo_plus import TRPOPlus

__all__ = ["TRPOPlus"]
