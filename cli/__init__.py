"""The ``zcut`` command line: the composition root, above every other package.

``cli/commands/`` holds every command and its options (one module per command, ``common.py`` for the
options several share); each reads its options into the library's options object and calls the
library (``studies.sweep.run``, ``studies.batch.run``, ``annotate.accuracy.run``, ...). ``cli.main``
imports the commands and turns their errors into messages and exit statuses (docs/cli.md). Nothing
imports ``cli``: the dependencies point down, zcut <- replay <- annotate <- studies <- cli.
"""
