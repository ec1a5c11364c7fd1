"""Studies over many frames: ``zcut batch`` (every frame of many logs, counted and scored) and
``zcut sweep`` (parameter studies scored by true accuracy), on local processes or a Ray cluster, and
``zcut compare`` (two filters on the same frames, in one process). Each is a library call with frozen
options (the commands, in ``cli/commands/``, read the command line into them).

Layers: it uses ``zcut`` (the filters), ``replay`` (logs, the replay session) and ``annotate``
(the truth and the accuracy report); nothing imports it but the console script.

- ``units``: a study's work, split into units of whole MCAP chunks of one log;
- ``executors``: running units on local processes (default) or Ray tasks (``--ray``);
- ``parts``: the output folder: one part file per finished unit, so that a rerun skips what is done;
- ``batch`` and ``sweep``: what a unit computes, and the tables and summaries made from the parts;
- ``report``: the sweep's plots and its HTML report;
- ``compare``: two filters on the same frames, with a paired verdict (docs/compare.md).
"""
