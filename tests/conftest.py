"""Shared test set-up: Hypothesis profiles and the fixtures several test modules use.

Layout: the folders mirror the packages (``env/<subpackage>``, ``controllers``, ``agents``, ``cli``
for ``wt_inspect``, ``px4``) plus ``project`` (docs, lint, layout, examples). Markers:
:func:`pytest_collection_modifyitems` marks every test ``unit`` or ``integration``: integration
are the ``cli``, ``px4`` and ``project`` folders, every ``slow`` test not marked ``unit`` by hand
(closed loops, training) and any test marked so by hand; the rest are unit. ``slow`` is a test of
about a second or more, so ``pytest -m "not slow" -n 2`` is the quick loop; a slow test of one
module against its reference (a solver against IPOPT, the planner against brute force) carries
``unit`` by hand.

Fixtures: ``params`` (the Matrice-100-like preset every controller test flies) and ``qp_cache_dir``
(one private compiled-library cache for the session's controller tests). The controller
tests' closed-loop harness (model plant, surface pass, loop) is the plain module
``tests/closed_loop.py``, imported by name.

Hypothesis profiles: CI runs are reproducible, local runs keep exploring.

``ci`` (selected when the ``CI`` environment variable is set to anything but ``""``/``0``/``false``,
as GitHub Actions, GitLab and most runners do; or with ``HYPOTHESIS_PROFILE=ci``) derandomises
example generation: every CI run draws the same examples from each test's strategy, so a red
build is a regression, not bad luck; no example database is written (a fresh checkout has none
anyway), the reproduction blob of a failure is printed and no deadline applies (a shared
CI machine's timing is not the code's). ``dev`` (the default) is Hypothesis'
normal random exploration with its local database, so a local run may still find new failing
cases - pin those with ``@example`` in the test.
"""
from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

from wt_inspect_env.physics.quadrotor import QuadrotorParams, get_preset

# Written out in full rather than relying on Hypothesis' own CI detection (6.x versions differ).
settings.register_profile("ci", derandomize=True, database=None, print_blob=True, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
# explicit: Hypothesis derandomises its default profile when it detects CI itself
settings.register_profile("dev", derandomize=False)


def _profile() -> str:
    explicit = os.environ.get("HYPOTHESIS_PROFILE")
    if explicit:
        return explicit
    ci = os.environ.get("CI", "").strip().lower()
    return "ci" if ci not in ("", "0", "false", "no") else "dev"


settings.load_profile(_profile())

#: folders whose tests exercise several packages together
INTEGRATION_FOLDERS = ("cli", "px4", "project")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark each test ``unit`` or ``integration`` (module docstring)."""
    root = os.path.dirname(os.path.abspath(__file__))
    for item in items:
        rel = os.path.relpath(str(item.path), root).split(os.sep)
        if item.get_closest_marker("integration") is None and (
                rel[0] in INTEGRATION_FOLDERS
                or (item.get_closest_marker("slow") is not None and item.get_closest_marker("unit") is None)):
            item.add_marker(pytest.mark.integration)
        if item.get_closest_marker("integration") is None:
            item.add_marker(pytest.mark.unit)


@pytest.fixture(scope="session")
def qp_cache_dir(tmp_path_factory) -> str:
    """A private code-generation cache (a fresh directory, not the user's cache) shared by the
    controller tests that compile their QP libraries: each problem is compiled once a session (per
    xdist worker) rather than once a module."""
    return str(tmp_path_factory.mktemp("qpcache"))


@pytest.fixture(scope="session")
def params() -> QuadrotorParams:
    """The Matrice-100-like preset (the paper's drone)."""
    return get_preset("matrice100")
