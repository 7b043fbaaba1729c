"""Shared pytest configuration: the ``slow`` marker runs only with TROLLEY_SLOW=1."""
from __future__ import annotations

import os

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: long test, run only with TROLLEY_SLOW=1")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if os.environ.get("TROLLEY_SLOW") == "1":
        return
    skip = pytest.mark.skip(reason="slow: set TROLLEY_SLOW=1 to run")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
