"""Command-line subcommands of ``wt-inspect`` that need only the environment package."""
