"""The ``zcut`` commands: one module per command, each with ``add_arguments(parser)`` and ``run(args) -> int``
(the options read into the library's options object, the library called, its result printed), and
``common.py`` for the options several commands share (docs/cli.md)."""
