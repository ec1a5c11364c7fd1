"""``zcut annotate`` and ``zcut accuracy`` (registered in ``cli.main.COMMANDS``)."""
