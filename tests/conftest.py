"""Shared fixtures and paths for the whole suite."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
EXAMPLES = SHARED / "examples"
PROGRAMS = ROOT / "tests" / "programs"


@pytest.fixture
def examples() -> Path:
    if not EXAMPLES.is_dir():  # the examples are the contract; their absence is a failure
        pytest.fail(f"the shared examples are missing: {EXAMPLES}")
    return EXAMPLES
