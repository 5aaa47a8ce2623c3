"""Fixtures shared across the test folders: one Dask LocalCluster (2 worker processes, started
when a test first asks for it) for the tests that compare Dask runs with in-process runs."""

from __future__ import annotations

import logging

import pytest


@pytest.fixture(scope="session")
def dask_cluster():
    distributed = pytest.importorskip("distributed")
    from rigcal.study.scale import NO_HTTP_PORT

    for name in ("distributed", "bokeh", "tornado"):
        logging.getLogger(name).setLevel(logging.ERROR)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, silence_logs=logging.ERROR,
                                  scheduler_kwargs=NO_HTTP_PORT) as cluster:
        yield cluster
