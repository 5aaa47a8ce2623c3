"""Independent tasks (a study's draws, a fleet's datasets) mapped in-process or over Dask.

:func:`task_runner` is a context manager that yields a :class:`Runner`; its
:meth:`Runner.map` calls ``fn(shared, item)`` for every item and returns the results **in item
order**, whatever order they finish in, so a run gives the same numbers serially and on a
cluster as long as ``fn`` depends only on its arguments (every study seeds its draws from the
study's seed and the draw's index, never from a shared random stream).

Schedulers (the ``--scheduler`` option of ``rigcal study`` and ``rigcal calibrate --batch``):

* ``serial``: in this process, one task after the other;
* ``local`` (the default): a :class:`distributed.LocalCluster` started for the run - one
  single-threaded worker process per core, no dashboard, its logs silenced - and closed after
  it (also on Ctrl-C);
* anything else is the address of a running Dask scheduler (``tcp://host:8786``): the tasks run
  there, the cluster is left running. Its workers must be able to import rigcal.

``shared`` (e.g. the dataset) is sent to the workers once (``scatter``), not with every task.
dask and distributed are imported only when a cluster is used.
"""

from __future__ import annotations

import logging
import os
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence

from rigcal.errors import InputError

SERIAL = "serial"
LOCAL = "local"
#: no dashboard, and the scheduler's small HTTP server (health, metrics) on a free local port
#: instead of 8787, which another cluster on the machine may hold
NO_HTTP_PORT = {"dashboard": False, "dashboard_address": "127.0.0.1:0"}

Progress = Callable[[int, int], None]


@dataclass
class Runner:
    """Maps tasks over ``client`` (a :class:`distributed.Client`) or, when it is None, in this
    process. ``description`` says where (for logs and study.json)."""

    client: Any = None
    description: str = SERIAL

    @property
    def workers(self) -> int:
        if self.client is None:
            return 1
        return max(1, len(self.client.scheduler_info().get("workers", {})))

    def map(self, fn: Callable[[Any, Any], Any], items: Sequence[Any], shared: Any = None,
            progress: Progress | None = None, name: str = "task") -> list[Any]:
        """``[fn(shared, item) for item in items]``, in item order. An exception raised by a
        task is raised here (the remaining tasks are cancelled)."""
        items = list(items)
        total = len(items)
        if progress:
            progress(0, total)
        if self.client is None:
            out = []
            for i, item in enumerate(items):
                out.append(fn(shared, item))
                if progress:
                    progress(i + 1, total)
            return out
        if not items:
            return []
        from distributed import as_completed

        remote = self.client.scatter(shared, broadcast=True, hash=False) if shared is not None else None
        # consecutive items in chunks: a task's round trip through the scheduler costs a few
        # milliseconds, as much as a small calibration; a few tasks per worker stay in flight
        size = chunk_size(total, self.workers)
        starts = list(range(0, total, size))
        chunks = [items[i:i + size] for i in starts]
        futures = self.client.map(_run_chunk, [fn] * len(chunks), [remote] * len(chunks), chunks, pure=False,
                                  key=[f"{name}-{os.getpid()}-{id(items)}-{i}" for i in starts])
        index = {f.key: i for f, i in zip(futures, starts)}
        out: list[Any] = [None] * total
        done = 0
        try:
            for fut in as_completed(futures):
                part = fut.result()
                at = index[fut.key]
                out[at:at + len(part)] = part
                done += len(part)
                if progress:
                    progress(done, total)
        finally:
            if done < total:
                self.client.cancel(futures)
        return out


#: items per Dask task at most, and chunks per worker at least (so that the last chunks, which
#: decide when a map ends, stay short)
MAX_CHUNK = 8
MIN_CHUNKS_PER_WORKER = 50


def chunk_size(total: int, workers: int) -> int:
    """Items per Dask task for ``total`` items on ``workers`` workers: 1 for a short map, up to
    MAX_CHUNK when there are many items."""
    return max(1, min(MAX_CHUNK, total // (max(workers, 1) * MIN_CHUNKS_PER_WORKER)))


def _run_chunk(fn: Callable[[Any, Any], Any], shared: Any, chunk: Sequence[Any]) -> list[Any]:
    return [fn(shared, item) for item in chunk]


#: what the local cluster's workers do not inherit from Dask's default environment
WORKER_ENV_DROPPED = ("MALLOC_TRIM_THRESHOLD_",)


def worker_environment() -> dict:
    """The environment Dask sets in a local worker before it starts (BLAS and OpenMP on one
    thread), without ``MALLOC_TRIM_THRESHOLD_``: set at all, it turns off glibc's adaptive
    mmap threshold, so every array above 128 kB a calibration allocates is a fresh mmap and
    page faults - the full Prius study spent 157 s of its 1212 s of CPU in the kernel (Fig. 7
    with 6 draws: 28.4 s with it, 24.1 s without, 21.2 s the ideal). A study's workers hold
    little memory, which the trim threshold is there to give back."""
    import dask
    import distributed  # noqa: F401 - registers the distributed.* configuration

    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {})
    for name in WORKER_ENV_DROPPED:
        env.pop(name, None)
    return env


def local_cluster(workers: int):
    """A :class:`distributed.LocalCluster` of ``workers`` single-threaded worker processes in
    :func:`worker_environment`, without dashboard, its logs silenced (close it after use)."""
    import dask
    from distributed import LocalCluster

    with dask.config.set({"distributed.nanny.pre-spawn-environ": worker_environment()}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            dashboard_address=None, silence_logs=logging.ERROR,
                            scheduler_kwargs=NO_HTTP_PORT)


@contextmanager
def task_runner(scheduler: str | None = LOCAL, workers: int | None = None,
                tasks: int | None = None) -> Iterator[Runner]:
    """A :class:`Runner` for ``scheduler`` (see the module docstring); ``workers``: processes
    of the local cluster (default: the number of cores). ``tasks``: how many tasks will run, if
    known - a local cluster is not started for a single task. The cluster and client are closed
    on exit, also when the block is interrupted."""
    scheduler = (scheduler or LOCAL).strip()
    if scheduler == SERIAL or (scheduler == LOCAL and tasks is not None and tasks <= 1):
        yield Runner()
        return
    from rigcal.extras import require

    Client = require("distributed", f"--scheduler {scheduler} (a Dask cluster; "
                     "--scheduler serial runs in this process without it)").Client
    cluster = client = None
    # distributed logs its scheduler's and workers' comings and goings at INFO in this process
    quiet = {name: logging.getLogger(name) for name in ("distributed", "bokeh", "tornado")}
    levels = {name: lg.level for name, lg in quiet.items()}
    for lg in quiet.values():
        lg.setLevel(logging.ERROR)
    try:
        if scheduler == LOCAL:
            n = workers or os.cpu_count() or 1
            cluster = local_cluster(n)
            client = Client(cluster)
            where = f"Dask LocalCluster, {n} worker process{'es' if n > 1 else ''}"
        else:
            try:
                client = Client(scheduler, timeout="10s")
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(f"--scheduler {scheduler}: cannot connect to a Dask scheduler there ({exc})") from None
            where = f"Dask scheduler {scheduler}"
        yield Runner(client, where)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        for name, lg in quiet.items():
            lg.setLevel(levels[name])
