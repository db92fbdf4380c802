"""Shared pytest options. `--station PATH` names a real station file and enables tests/hw."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI does: BLAS threads thrash on 2 cores

import signal  # noqa: E402

import pytest  # noqa: E402


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--station", action="store", default=None, metavar="PATH",
                     help="a real station file: runs the opt-in hardware tests in tests/hw")


@pytest.fixture
def station_path(request: pytest.FixtureRequest) -> str:
    path = request.config.getoption("--station")
    if path is None:
        pytest.skip("hardware test: give --station PATH to run it")
    return path


SLOW_FIRST = ("tests/system/", "tests/unit/report/", "tests/unit/rig/test_design_cli.py")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The long tests first, so that spread over workers they do not all end last (the order of the
    tests within each group is kept)."""
    def rank(item: pytest.Item) -> int:
        path = item.nodeid
        return next((i for i, prefix in enumerate(SLOW_FIRST) if path.startswith(prefix)), len(SLOW_FIRST))

    items.sort(key=rank)


@pytest.fixture
def default_sigint():
    """Ctrl-C as an interactive Python has it (KeyboardInterrupt), whatever the process that runs the
    tests inherited: a shell's background job, or a test worker, starts with SIGINT ignored."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)
