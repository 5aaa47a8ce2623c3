"""Independent tasks (a study's draws, a fleet's datasets) mapped in-process or over Dask.

:func:`task_runner` is a context manager that yields a :class:`Runner`; its
:meth:`Runner.map` calls ``fn(shared, item)`` for every item and returns the results **in item
order**, whatever order they finish in, so a run gives the same numbers serially and on a
cluster as long as ``fn`` depends only on its arguments (every study seeds its draws from the
study's seed and the draw's index, never from a shared random stream).
:meth:`Runner.run_each` is the same map for callers that act on each result as it comes
(a fleet writes each dataset's result as soon as it is calibrated).

Schedulers (the ``--scheduler`` option of ``rigcal study`` and ``rigcal calibrate --batch``):

* ``serial``: in this process, one task after the other;
* ``local`` (the default): a :class:`distributed.LocalCluster` started for the run - one
  single-threaded worker process per core, no dashboard, its logs silenced - and closed after
  it (also on Ctrl-C: an interrupt during the cluster's start or stop is held until it is
  done, so no worker process is left behind);
* anything else is the address of a running Dask scheduler (``tcp://host:8786``, or
  ``host:port``; ``tls://`` with Dask's TLS settings in its configuration): the tasks run
  there, the cluster is left running. Its workers must be able to import rigcal. Before any
  task, :func:`check_scheduler` makes sure a Dask scheduler answers there within
  :data:`PROBE_TIMEOUT_S` (a port where nothing listens, a service that says nothing or
  something else, an unroutable address are all refused in that time, saying which), and the
  scheduler must have a worker within :data:`WORKER_WAIT_S`.

A cluster that loses a worker: the tasks it held run again on the others (at most
:data:`MAX_ATTEMPTS` times each). A cluster that loses its scheduler, or all its workers for
:data:`WORKERS_GONE_S`: the results already received are kept; the rest are reported
missing (:class:`MapReport`) or, with ``finish_here``, run in this process.

``shared`` (e.g. the dataset) is sent to the workers once (``scatter``), not with every task.
dask and distributed are imported only when a cluster is used.
"""

from __future__ import annotations

import logging
import os
import socket
import struct
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Mapping, NamedTuple, Sequence

from rigcal import interrupts
from rigcal.errors import InputError, RigcalError

log = logging.getLogger(__name__)

SERIAL = "serial"
LOCAL = "local"
#: no dashboard, and the scheduler's small HTTP server (health, metrics) on a free local port
#: instead of 8787, which another cluster on the machine may hold
NO_HTTP_PORT = {"dashboard": False, "dashboard_address": "127.0.0.1:0"}
#: a scheduler address must answer as Dask does within this time [s] (with the start of
#: the command, the user hears within 5 s)
PROBE_TIMEOUT_S = 4.0
#: a scheduler must have a worker within this time [s] before any task is sent
WORKER_WAIT_S = 5.0
#: a running map gives up on a scheduler without any worker for this long [s]
WORKERS_GONE_S = 15.0
#: how often a task whose worker was lost is sent at most
MAX_ATTEMPTS = 3
#: Dask's default port (an address without one)
DEFAULT_PORT = 8786
#: how often a running map asks the scheduler how it is [s]
HEALTH_EVERY_S = 1.0

Progress = Callable[[int, int], None]


class MapReport(NamedTuple):
    """What :meth:`Runner.run_each` could not do: ``missing`` maps the index of every item
    without a result to the reason; ``lost`` says what happened to the cluster (None when it
    stayed up); ``here`` counts the items run in this process after it was lost."""

    missing: Mapping[int, str]
    lost: str | None = None
    here: int = 0


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
            progress: Progress | None = None, name: str = "task",
            on_result: Callable[[int, Any], None] | None = None) -> list[Any]:
        """``[fn(shared, item) for item in items]``, in item order. An exception raised by a
        task is raised here (the remaining tasks are cancelled). A lost scheduler does not end
        the map: what is left runs in this process (with a warning logged); a task that kills
        its worker every time is a RigcalError. ``on_result(index, result)`` is called in this
        process as each item's result arrives (e.g. to write it at once)."""
        items = list(items)
        out: list[Any] = [None] * len(items)

        def keep(i: int, value: Any) -> None:
            out[i] = value
            if on_result:
                on_result(i, value)

        report = self.run_each(fn, items, shared, on_result=keep, progress=progress, name=name, finish_here=True)
        if report.missing:
            i, why = next(iter(sorted(report.missing.items())))
            raise RigcalError(f"{self.description}: {len(report.missing)} of {len(items)} {name} tasks could not "
                              f"run (item {i}: {why})")
        return out

    def run_each(self, fn: Callable[[Any, Any], Any], items: Sequence[Any], shared: Any = None, *,
                 on_result: Callable[[int, Any], None], progress: Progress | None = None,
                 name: str = "task", finish_here: bool = False) -> MapReport:
        """Call ``fn(shared, item)`` for every item and ``on_result(index, value)`` in this
        process as each result arrives (in any order on a cluster). ``progress(done, total)``
        after each. A task's exception is raised here (the rest are cancelled); ``fn`` should
        return its expected failures as values.

        On a cluster, a task whose worker was lost runs again (at most :data:`MAX_ATTEMPTS`
        times); when the scheduler is lost or has had no worker for :data:`WORKERS_GONE_S`,
        the results already received stay delivered and the other items are run in this
        process (``finish_here``) or returned as missing. Returns a :class:`MapReport`."""
        items = list(items)
        total = len(items)
        if progress:
            progress(0, total)
        if self.client is None:
            for i, item in enumerate(items):
                on_result(i, fn(shared, item))
                if progress:
                    progress(i + 1, total)
            return MapReport({})
        if not items:
            return MapReport({})
        return _DaskMap(self, fn, items, shared, on_result, progress, name, finish_here).run()


class _DaskMap:
    """One :meth:`Runner.run_each` on a Dask cluster: the chunks still open, their attempts, the
    cluster's health."""

    def __init__(self, runner: Runner, fn, items, shared, on_result, progress, name, finish_here):
        self.client = runner.client
        self.where = runner.description
        self.fn, self.items, self.shared = fn, items, shared
        self.on_result, self.progress, self.name, self.finish_here = on_result, progress, name, finish_here
        self.total = len(items)
        # consecutive items in chunks: a task's round trip through the scheduler costs a few
        # milliseconds, as much as a small calibration; a few tasks per worker stay in flight
        size = chunk_size(self.total, runner.workers)
        self.chunks = {start: items[start:start + size] for start in range(0, self.total, size)}
        self.open = set(self.chunks)  # chunk starts neither delivered nor given up
        self.attempts = dict.fromkeys(self.chunks, 0)
        self.futures: dict[str, tuple[int, Any]] = {}  # key -> (chunk start, future) of the chunks in flight
        self.missing: dict[int, str] = {}
        self.done = 0
        self.remote = None
        self.no_workers_since: float | None = None

    def run(self) -> MapReport:
        from distributed import as_completed

        self.ac = as_completed()
        lost = None
        try:
            self._scatter()
            for start in self.chunks:
                self._submit(start)
            lost = self._collect()
        except (OSError, TimeoutError) as exc:  # the scheduler went away while tasks were sent
            lost = f"lost the Dask scheduler ({type(exc).__name__}: {exc})"
        finally:
            if self.futures and self.client.status == "running":
                try:
                    self.client.cancel([f for _, f in self.futures.values()])
                except Exception:  # noqa: BLE001 - the scheduler may be gone; nothing to cancel then
                    pass
        if lost is None:
            return MapReport(self.missing)
        left = sorted(self.open)
        count = sum(len(self.chunks[s]) for s in left)
        if self.finish_here:
            log.warning("note: %s: %s; the other %d of %d %s tasks run in this process", self.where, lost, count,
                        self.total, self.name)
            for start in left:
                self._deliver(start, [self.fn(self.shared, item) for item in self.chunks[start]])
            return MapReport(self.missing, lost, count)
        for start in left:
            self._give_up(start, lost)
        return MapReport(self.missing, lost)

    def _scatter(self) -> None:
        if self.shared is not None:
            self.remote = self.client.scatter(self.shared, broadcast=True, hash=False)

    def _submit(self, start: int) -> None:
        attempt = self.attempts[start]
        key = f"{self.name}-{os.getpid()}-{id(self.items)}-{start}" + (f"-retry{attempt}" if attempt else "")
        fut = self.client.submit(_run_chunk, self.fn, self.remote, self.chunks[start], key=key, pure=False)
        self.futures[fut.key] = (start, fut)
        self.ac.add(fut)

    def _deliver(self, start: int, part: list) -> None:
        self.open.discard(start)
        for j, value in enumerate(part):
            self.on_result(start + j, value)
        self.done += len(part)
        if self.progress:
            self.progress(self.done + len(self.missing), self.total)

    def _give_up(self, start: int, why: str) -> None:
        self.open.discard(start)
        for j in range(len(self.chunks[start])):
            self.missing[start + j] = why

    def _collect(self) -> str | None:
        """Deliver results as they come; the reason the cluster was given up on, or None."""
        from concurrent.futures import CancelledError

        from distributed.scheduler import KilledWorker

        last = time.monotonic()
        while not self.ac.is_empty():
            if not self.ac.has_ready():
                now = time.monotonic()
                if now - last >= HEALTH_EVERY_S:
                    last = now
                    lost = self._health()
                    if lost:
                        return lost
                time.sleep(0.02)
                continue
            fut = next(self.ac)
            start, _ = self.futures.pop(fut.key)
            try:
                part = fut.result()
            except KilledWorker:
                self._give_up(start, "the workers running it died every time (out of memory, or a crash in "
                                     "the worker)")
                continue
            except (CancelledError, OSError):
                if fut.status == "error":  # the task's own exception (an OSError it raised)
                    raise
                # its worker (or the worker holding the shared data) was lost, or the scheduler
                lost = self._health(worker_lost=True)
                if lost:
                    return lost
                self.attempts[start] += 1
                if self.attempts[start] >= MAX_ATTEMPTS:
                    self._give_up(start, f"its worker was lost {MAX_ATTEMPTS} times while running it")
                    continue
                if self.remote is not None and self.remote.status != "finished":
                    self._scatter()  # the shared data went with the worker
                self._submit(start)
                continue
            self._deliver(start, part)
        return None

    def _health(self, worker_lost: bool = False) -> str | None:
        """Why the cluster cannot finish the map (its scheduler is gone, or it has had no worker
        for WORKERS_GONE_S), or None. After a lost worker, waits for one when none is left (a
        nanny restarts its worker in a few seconds)."""
        while True:
            if self.client.status != "running":
                return "lost the connection to the Dask scheduler"
            try:
                workers = self.client.sync(self.client.scheduler.ncores, callback_timeout=PROBE_TIMEOUT_S)
            except Exception as exc:  # noqa: BLE001 - any failure to answer is a lost scheduler
                return f"the Dask scheduler stopped answering ({type(exc).__name__})"
            if workers:
                self.no_workers_since = None
                return None
            now = time.monotonic()
            if self.no_workers_since is None:
                self.no_workers_since = now
            if now - self.no_workers_since >= WORKERS_GONE_S:
                return f"the Dask scheduler has had no worker for {WORKERS_GONE_S:g} s"
            if not worker_lost:
                return None
            time.sleep(0.2)


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
    :func:`worker_environment`, without dashboard, its logs silenced (close it after use). The
    workers log nothing below CRITICAL: when the run is interrupted, a worker that outlives
    its scheduler by a moment would otherwise print a traceback of its failed heartbeat."""
    import dask
    from distributed import LocalCluster

    with dask.config.set({"distributed.nanny.pre-spawn-environ": worker_environment()}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            dashboard_address=None, silence_logs=logging.CRITICAL,
                            scheduler_kwargs=NO_HTTP_PORT)


# --------------------------------------------------------------------------------------------
# a scheduler's address


def _tls_configured() -> bool:
    import dask
    import distributed  # noqa: F401 - registers the distributed.* configuration

    tls = dask.config.get("distributed.comm.tls", default={}) or {}
    return bool(tls.get("ca-file") or (tls.get("client") or {}).get("cert"))


def parse_scheduler_address(address: str) -> tuple[str, str, int]:
    """(scheme, host, port) of a ``--scheduler`` address (``tcp://host:port``, ``host:port``,
    ``tls://host:port``; the port defaults to Dask's 8786). InputError naming the address and
    what is expected for anything else - another transport, a missing host, a port that is not
    a number from 1 to 65535."""
    shown = _shown(address)
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    scheme = scheme.lower()
    if scheme == "ucx":
        import importlib.util

        if importlib.util.find_spec("distributed_ucxx") is None:
            raise InputError(f"--scheduler {shown}: ucx:// needs Dask's UCX transport (the distributed-ucxx "
                             "package), which is not installed; give the scheduler's tcp:// address")
    elif scheme == "tls":
        if not _tls_configured():
            raise InputError(f"--scheduler {shown}: tls:// needs Dask's TLS settings (distributed.comm.tls.ca-file "
                             "and .client.cert/.key in the Dask configuration), and none are set")
    elif scheme != "tcp":
        raise InputError(f"--scheduler {shown}: expected 'local', 'serial' or a Dask scheduler's address "
                         f"(tcp://HOST:PORT, or tls:// with Dask's TLS settings), got {scheme}://")
    rest = rest.split("/", 1)[0]
    if rest.startswith("["):  # [IPv6]:port
        host, _, port_text = rest[1:].partition("]")
        port_text = port_text.lstrip(":")
    else:
        host, _, port_text = rest.rpartition(":") if ":" in rest else (rest, "", "")
    if not host:
        raise InputError(f"--scheduler {shown}: no host in the address; expected e.g. tcp://10.0.0.5:8786")
    if not port_text:
        return scheme, host, DEFAULT_PORT
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise InputError(f"--scheduler {shown}: port {port_text!r} is not a number from 1 to 65535")
    return scheme, host, int(port_text)


def _shown(text: str) -> str:
    """``text`` for a message: control characters escaped, cut at 200 characters."""
    from rigcal.errors import printable

    return printable(text if len(text) <= 200 else text[:200] + "...")


#: the most bytes a Dask scheduler's greeting (its handshake, a few hundred bytes) may announce
_MAX_GREETING = 1 << 20


def _probe(scheme: str, host: str, port: int, deadline: float) -> str | None:
    """None when a Dask scheduler answers at ``host:port`` before ``deadline`` (monotonic
    time), else what was found instead. A Dask server greets every connection with its
    handshake (8 bytes of length, then msgpack frames naming its compression, Python and
    pickle protocol) before reading anything; for tls:// only the TCP connection is tried."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError) as exc:
        return f"cannot resolve host {host!r} ({getattr(exc, 'strerror', None) or exc})"
    last = "no address"
    for family, kind, proto, _, addr in infos:
        sock = socket.socket(family, kind, proto)
        try:
            sock.settimeout(max(0.05, deadline - time.monotonic()))
            try:
                sock.connect(addr)
            except socket.timeout:
                return f"no answer to a connection within {PROBE_TIMEOUT_S:g} s (an unroutable address, or a firewall?)"
            except OSError as exc:
                last = ("nothing listens there (connection refused)" if isinstance(exc, ConnectionRefusedError)
                        else f"cannot connect ({exc.strerror or exc})")
                continue
            if scheme == "tls":
                return None
            return _greeting(sock, deadline)
        finally:
            sock.close()
    return last


def _greeting(sock: socket.socket, deadline: float) -> str | None:
    not_dask = "the service there is not a Dask scheduler: it {}"
    head = _read(sock, 8, deadline)
    if head is None:
        return not_dask.format(f"sent nothing within {PROBE_TIMEOUT_S:g} s (a Dask scheduler greets at once)")
    if len(head) < 8:
        return not_dask.format(f"sent {_bytes(head)} and then nothing")
    (size,) = struct.unpack("<Q", head)
    if not 16 <= size <= _MAX_GREETING:
        return not_dask.format(f"began with {_bytes(head)}")
    body = _read(sock, size, deadline)
    if body is None or b"pickle-protocol" not in body or b"compression" not in body:
        return not_dask.format(f"began with {_bytes(head + (body or b''))}")
    return None


def _read(sock: socket.socket, n: int, deadline: float) -> bytes | None:
    """Up to ``n`` bytes (fewer when the peer closes); None when none came before ``deadline``."""
    data = b""
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            return data or None
        sock.settimeout(left)
        try:
            more = sock.recv(n - len(data))
        except socket.timeout:
            return data or None
        except OSError:
            break
        if not more:
            break
        data += more
    return data


def _bytes(data: bytes) -> str:
    return repr(data[:24]) + ("..." if len(data) > 24 else "")


def check_scheduler(address: str, timeout_s: float = PROBE_TIMEOUT_S) -> None:
    """Make sure a Dask scheduler answers at ``address`` (see :func:`parse_scheduler_address`)
    within ``timeout_s``, name resolution included; InputError naming the address and what was
    found otherwise (refused, silent, another service, unroutable). Sends nothing: it reads the
    greeting every Dask server sends first."""
    scheme, host, port = parse_scheduler_address(address)
    deadline = time.monotonic() + timeout_s
    found: list[str | None] = []
    # in a thread: a name lookup may take longer than the deadline and cannot be given one
    probe = threading.Thread(target=lambda: found.append(_probe(scheme, host, port, deadline)), daemon=True,
                             name="rigcal-scheduler-probe")
    probe.start()
    probe.join(timeout_s + 0.5)
    if not found:
        why = f"no answer within {timeout_s:g} s (the host name did not resolve in time)"
    else:
        why = found[0]
    if why is not None:
        raise InputError(f"--scheduler {_shown(address)}: {why}; expected a running Dask scheduler "
                         "(dask scheduler), 'local' or 'serial'")


def _connect(address: str):
    """A :class:`distributed.Client` of the scheduler at ``address`` that has a worker."""
    from distributed import Client

    check_scheduler(address)
    shown = _shown(address)
    try:
        client = Client(address, timeout=f"{PROBE_TIMEOUT_S:g}s")
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise InputError(f"--scheduler {shown}: cannot connect to the Dask scheduler there "
                         f"({type(exc).__name__}: {exc})") from None
    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
    except (TimeoutError, OSError) as exc:
        client.close(timeout=PROBE_TIMEOUT_S)
        if isinstance(exc, TimeoutError):
            raise InputError(f"--scheduler {shown}: the Dask scheduler there has no worker (waited "
                             f"{WORKER_WAIT_S:g} s); start one with: dask worker {shown}") from None
        raise InputError(f"--scheduler {shown}: lost the Dask scheduler while waiting for a worker "
                         f"({exc})") from None
    return client


@contextmanager
def task_runner(scheduler: str | None = LOCAL, workers: int | None = None,
                tasks: int | None = None) -> Iterator[Runner]:
    """A :class:`Runner` for ``scheduler`` (see the module docstring); ``workers``: processes
    of the local cluster (default: the number of cores). ``tasks``: how many tasks will run, if
    known - a local cluster is not started for a single task. The cluster and client are closed
    on exit, also when the block is interrupted. A scheduler address is checked first
    (:func:`check_scheduler`, a worker within :data:`WORKER_WAIT_S`): InputError naming it."""
    scheduler = (scheduler or LOCAL).strip()
    if scheduler == SERIAL or (scheduler == LOCAL and tasks is not None and tasks <= 1):
        yield Runner()
        return
    from rigcal.extras import require

    Client = require("distributed", f"--scheduler {scheduler} (a Dask cluster; "
                     "--scheduler serial runs in this process without it)").Client
    cluster = client = None
    quiet_dask_logs()
    try:
        if scheduler == LOCAL:
            n = workers or os.cpu_count() or 1
            with interrupts.deferred():  # the cluster exists whole (and is closed below) or not at all
                from distributed import Client

                cluster = local_cluster(n)
                client = Client(cluster)
            where = f"Dask LocalCluster, {n} worker process{'es' if n > 1 else ''}"
        else:
            client = _connect(scheduler)
            where = f"Dask scheduler {_shown(scheduler)}"
        yield Runner(client, where)
    finally:
        with interrupts.deferred(raise_after=False):
            if client is not None:
                try:
                    client.close(timeout=PROBE_TIMEOUT_S)
                except Exception:  # noqa: BLE001 - a lost scheduler: nothing left to close
                    pass
            if cluster is not None:
                cluster.close()


def quiet_dask_logs() -> None:
    """Silence distributed's logs in this process below CRITICAL, for good: it logs its
    scheduler's and workers' comings and goings, and a lost scheduler as ERRORs with tracebacks
    - also from its event loop's thread after the client was closed -, where the runner says
    in one line what happened. The same for asyncio's own logger: a scheduler torn down by
    Ctrl-C / SIGTERM while a scatter was in flight leaves a task whose KeyError asyncio
    reports as "Task exception was never retrieved" with a traceback (seen in CI); the event
    loop here is Dask's alone."""
    import distributed  # noqa: F401 - it sets its loggers' levels when imported

    prefixes = ("distributed", "bokeh", "tornado", "asyncio")
    for name in list(logging.root.manager.loggerDict):  # its own levels: distributed.client, ...
        if name.split(".")[0] in prefixes:
            logging.getLogger(name).setLevel(logging.CRITICAL)
    for name in prefixes:
        logging.getLogger(name).setLevel(logging.CRITICAL)
