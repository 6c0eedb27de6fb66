"""Subcommands of ``wt-inspect`` (see :mod:`wt_inspect.cli`): those that wire several layers together,
``plan`` and the environment's benchmarks (``bench sim/coverage/env/vecenv/planner/leak``), which
moved here from ``wt_inspect_env`` so that the environment package holds the environment only."""
