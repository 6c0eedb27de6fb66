"""Compatibility shim: the ``wt-inspect`` dispatcher moved to :mod:`wt_inspect.cli`.

Kept only while work started against the old path is re-pointed (the console script already runs
``wt_inspect.cli:main``); it is the one module of this package that reaches above it, and it will
be deleted. Add new subcommands to the tables in ``wt_inspect/cli.py``.
"""
from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    """Run ``wt_inspect.cli.main`` (imported here, at call time, so importing this package never
    imports the layers above it)."""
    from wt_inspect.cli import main as _main
    return _main(argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
