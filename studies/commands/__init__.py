"""``zcut batch`` and ``zcut sweep`` (registered in ``replay.cli.COMMANDS``)."""
