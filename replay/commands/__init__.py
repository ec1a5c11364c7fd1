"""Subcommands of the ``zcut`` console script: each module has ``add_arguments(p)`` and ``run(args) -> int``."""
