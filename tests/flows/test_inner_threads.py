"""A run on local threads gives its cores to its tasks: BLAS and OpenMP run one thread per
task meanwhile (the libraries' own thread pools spun on a set's small matrices)."""

import numpy as np
from threadpoolctl import threadpool_info

from spectralize.flows.dask_setup import INNER_THREADS, dask_scheduler


def _blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_local_threads_run_blas_with_inner_threads_and_give_the_default_back():
    np.ones((4, 4)) @ np.ones((4, 4))  # numpy's BLAS is loaded
    before = _blas_threads()
    assert before, "no BLAS library found by threadpoolctl"
    with dask_scheduler(None, log=lambda _: None) as parallel:
        assert parallel >= 1
        assert _blas_threads() == [INNER_THREADS] * len(before)
    assert _blas_threads() == before
