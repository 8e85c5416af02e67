"""What every sub-package shares and that depends on none of them: the rules user-facing arguments are checked by
(:mod:`~sb3_trpo_plus.common.arguments`) and atomic file writes (:mod:`~sb3_trpo_plus.common.persistence`)."""
