"""One module per ``ebr`` subcommand (see :mod:`ebr_mitsuba.cli`)."""
