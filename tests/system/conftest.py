"""Fixtures of the system tests: a throwaway PostgreSQL server for the fleet database tests. Every test in
this folder is marked `system` (the inner loop is `pytest -m "not system"`)."""

from __future__ import annotations

import itertools

import pytest

from tests import pg_server

_names = itertools.count(1)


@pytest.fixture(scope="session")
def pg():
    """One PostgreSQL server for the whole run (127.0.0.1, a free port); skipped where none can start."""
    try:
        server = pg_server.start()
    except pg_server.PgUnavailable as exc:
        pytest.skip(f"no PostgreSQL server for the fleet tests: {exc}")
    yield server
    server.stop()


@pytest.fixture
def fleet_db(pg) -> str:
    """The URL of a fresh, empty database on that server."""
    return pg_server.create_database(pg, f"fleet_test_{next(_names)}")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if "tests/system/" in item.nodeid or item.nodeid.startswith("system/"):
            item.add_marker(pytest.mark.system)
