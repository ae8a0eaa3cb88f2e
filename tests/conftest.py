"""Fixtures shared by every test module: where the repository and the shared data are, the
Hypothesis profiles, and a private folder for device locks.

The Hypothesis profile drops the per-example deadline (200 ms), which measures the machine
rather than the code: a loaded CI machine can stall one example past it, and Hypothesis then
reports a flaky test. ``HYPOTHESIS_SCALE=N`` multiplies every property test's number of examples
(here and through ``helpers.examples``), for a bug hunt: ``make test-thorough``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

from helpers import examples

settings.register_profile("admittance", deadline=None, max_examples=examples(100))
settings.load_profile("admittance")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
REAL_DATA = SHARED / "data" / "real"
THESIS_DATA = SHARED / "data" / "thesis"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The measured data of ../shared/data/real; tests that need it skip when it is absent."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"measured data not found at {REAL_DATA} (the shared/ folder is not beside the repo)")
    return REAL_DATA


@pytest.fixture(scope="session")
def thesis_data() -> Path:
    if not THESIS_DATA.is_dir():
        pytest.skip(f"thesis tables not found at {THESIS_DATA}")
    return THESIS_DATA


@pytest.fixture(scope="session", autouse=True)
def private_lock_dir(tmp_path_factory):
    """Device claims (admittance.drivers.ports) of this run's daemons go to a folder of its own,
    not /run/lock: concurrent test runs never see each other's, and nothing is left behind."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("ADMITTANCE_LOCK_DIR", str(tmp_path_factory.mktemp("locks")))
        yield
