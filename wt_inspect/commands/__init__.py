"""Subcommands of ``wt-inspect`` that wire several layers together (see :mod:`wt_inspect.cli`)."""
