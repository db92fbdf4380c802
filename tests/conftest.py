"""Shared pytest options. `--station PATH` names a real station file and enables tests/hw."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI does: BLAS threads thrash on 2 cores

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
