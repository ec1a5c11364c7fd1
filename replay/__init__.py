"""Logs and the pipeline run: reading and writing logs, running the filters on a log, logging to Rerun.

- ``logs``: MCAP logs read (damage-tolerant) and written, the ROS 2 codecs, PCD and PLY files, the
  names of docs/formats.md;
- ``pipeline``: the config, the filter methods, the stages of a frame, the replay session and its
  sinks (the results file, Rerun);
- ``synth``: synthetic logs with exact truth (above the pipeline: the pipeline does not import it);
- ``outputs`` (outputs that never replace an input), ``process`` (exit statuses, signals),
  ``presets`` (part and bin geometry), ``warmup`` (the numba kernels compiled ahead).

It imports ``zcut`` only; the commands live in ``cli`` (docs/architecture.md).
"""
