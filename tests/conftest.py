"""Fixtures shared across the test folders: one Dask LocalCluster (2 worker processes, started
when a test first asks for it) for the tests that compare Dask runs with in-process runs."""

from __future__ import annotations

import logging

import pytest


@pytest.fixture(scope="session")
def dask_cluster():
    pytest.importorskip("distributed")
    from rigcal.study.scale import local_cluster

    for name in ("distributed", "bokeh", "tornado"):
        logging.getLogger(name).setLevel(logging.ERROR)
    with local_cluster(2) as cluster:
        yield cluster
