"""The filters run on a log (docs/pipeline.md; docs/architecture.md, "The one way a frame travels"):
the config and its resolution (``config``), the filter registry (``methods``), the stages of one frame
(``stages``), the replay session (``session``), where its results go (``sinks``, ``viz`` for Rerun) and
the bin model a log is replayed with (``bin_model``)."""
