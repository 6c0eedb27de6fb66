"""wt_inspect: what sits above the environment, the controllers and the agents.

* :mod:`wt_inspect.cli` - the ``wt-inspect`` command dispatcher;
* :mod:`wt_inspect.evaluation` - the evaluation harness (scenarios, runner, backends, report,
  figures) and the registry that finds policies through entry points;
* :mod:`wt_inspect.commands` - subcommands that need several layers (``bench solver``).

Nothing below imports this package: ``wt_inspect_env`` <- ``controllers``, ``agents`` <- ``wt_inspect``.
"""
