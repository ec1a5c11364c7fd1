"""``zcut annotate`` and ``zcut accuracy`` (registered in ``replay.cli.COMMANDS``)."""
