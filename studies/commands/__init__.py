"""``zcut batch`` and ``zcut sweep`` (registered in ``cli.main.COMMANDS``)."""
