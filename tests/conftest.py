"""Shared test fixtures: the real data folder ../shared/data beside the repository."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("TAVF_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_path(*parts: str) -> Path:
    """Path of a file under ../shared/data; skips the test if the folder is absent (fails under CI=true)."""
    path = SHARED_DATA.joinpath(*parts)
    if not SHARED_DATA.is_dir():
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"shared data folder {SHARED_DATA} is missing in CI")
        pytest.skip(f"shared data folder {SHARED_DATA} not present")
    if not path.exists():
        pytest.fail(f"expected shared data file {path} is missing")
    return path


@pytest.fixture
def shared():
    """``shared('xodr', 'esmini', 'e6mini.xodr')`` -> Path, skipping or failing as shared_path does."""
    return shared_path
