"""Subcommands of the ``wfjax`` command line (see :mod:`wfjax.cli`)."""
