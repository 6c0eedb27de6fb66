"""Utilities with no knowledge of the inspection: input validation, atomic file output, the guarded
cache of compiled native libraries, signal handling, process memory, figure output and Ray start-up.

The bottom layer: imports nothing else from ``wt_inspect_env`` (``tests/project/test_layout.py`` checks
every subpackage's imports against its declared layer).
"""
