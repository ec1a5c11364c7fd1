"""Logs, synthetic scenes, the pipeline run, Rerun logging and the CLI of zcut."""
