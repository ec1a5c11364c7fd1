"""The ``zcut`` command line: the composition root, above every other package.

``cli.main`` imports the commands of ``replay``, ``annotate`` and ``studies`` and turns their errors
into messages and exit statuses (docs/cli.md). Nothing imports ``cli``: the dependencies point down,
zcut <- replay <- annotate <- studies <- cli.
"""
