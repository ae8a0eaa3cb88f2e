"""`identify` runs NumPy's BLAS on one thread (ident/identify.py, one_blas_thread) and gives the
process its threads back after, also when it fails.

Why it matters: BLAS threads spinning beside the Rust plant's own took 18–28 % more CPU on 30 drops
with a drag, on a 2-core machine with another job running (docs/identification-speed-log.md,
*Parameter sets side by side, with a smaller substep: kept*)."""

from __future__ import annotations

import pytest
from threadpoolctl import threadpool_info

from admittance.formats.dataset import load_dataset
from admittance.ident import identify
from admittance.ident.identify import IdentifySettings, identify_dataset
from admittance.ident.synthetic import SynthSpec, generate


def blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return load_dataset(generate(tmp_path_factory.mktemp("blas"), SynthSpec(n_trials=4, duration=3.0, seed=3)))


def test_identify_runs_blas_on_one_thread_and_restores_it(small, monkeypatch):
    before = blas_threads()
    assert before, "NumPy's BLAS is visible to threadpoolctl"
    seen: list[list[int]] = []
    run = identify._run

    def watched(*args, **kwargs):
        seen.append(blas_threads())
        return run(*args, **kwargs)

    monkeypatch.setattr(identify, "_run", watched)
    identify_dataset(small, IdentifySettings(max_effects=0))
    assert seen == [[1] * len(before)]
    assert blas_threads() == before


def test_blas_threads_are_given_back_when_identify_fails(small, monkeypatch):
    before = blas_threads()

    def fails(*args, **kwargs):
        raise RuntimeError("a failure inside the identification")

    monkeypatch.setattr(identify, "_run", fails)
    with pytest.raises(RuntimeError):
        identify_dataset(small)
    assert blas_threads() == before
