"""``python -m sb3_trpo_plus`` is the ``trpo-plus`` command."""

from sb3_trpo_plus.application.cli import main

main()
