"""Hostile clusters (issue #22): ``--scheduler`` addresses that are not a Dask scheduler - a fake
TCP service on a loopback port that says nothing, one that sends a banner, a port where nothing
listens -, transports rigcal cannot use, a scheduler without workers, and clusters that lose a
worker or their scheduler in the middle of a run (a real ``dask scheduler`` process, killed).

Every refusal is one ``rigcal: error:`` line naming the address and what was found, within
seconds (a scheduler that does not answer as Dask does is given up on in at most 5 s), before
anything is computed or written.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

pytest.importorskip("distributed")

#: the tasks below run on workers that cannot import this test module: sent by value
import cloudpickle  # noqa: E402

cloudpickle.register_pickle_by_value(sys.modules[__name__])

BANNER = b"SSH-2.0-OpenSSH_9.2p1 Debian-2\r\n"
HTTP = b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n"


@contextmanager
def fake_service(greeting: bytes | None):
    """A TCP service on a free loopback port that accepts every connection, sends ``greeting``
    (None: nothing) and keeps the connection open; yields the port."""
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", 0))
    server.listen(16)
    server.settimeout(0.1)
    held: list[socket.socket] = []
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            held.append(conn)
            if greeting is not None:
                try:
                    conn.sendall(greeting)
                except OSError:
                    pass

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield server.getsockname()[1]
    finally:
        stop.set()
        thread.join(2)
        for conn in held:
            conn.close()
        server.close()


def _closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    """Six small simulated datasets car0..car5 (8 boards each)."""
    root = tmp_path_factory.mktemp("fleet")
    sensors = prius_like_rig()
    for k in range(6):
        rng = np.random.default_rng(40 + k)
        sim = simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)
        write_dataset(sim.dataset, root / f"car{k}")
    return root


# ---------------------------------------------------------------------------------------------
# addresses that are not a Dask scheduler


@pytest.mark.parametrize("greeting, expected", [
    (None, "sent nothing within 4 s"),
    (BANNER, "began with b'SSH-2.0-"),
    (HTTP, "began with b'HTTP/1.1'"),
    (b"x", "sent b'x' and then nothing"),
])
def test_a_service_that_is_not_a_dask_scheduler_is_given_up_within_5_s(greeting, expected):
    from rigcal.study.scale import check_scheduler

    with fake_service(greeting) as port:
        t0 = time.monotonic()
        with pytest.raises(InputError, match=rf"--scheduler tcp://127\.0\.0\.1:{port}: the service there is not a "
                                             rf"Dask scheduler: it {re.escape(expected)}"):
            check_scheduler(f"tcp://127.0.0.1:{port}")
        assert time.monotonic() - t0 <= 5.0


def test_a_port_where_nothing_listens_is_refused_at_once():
    from rigcal.study.scale import check_scheduler

    port = _closed_port()
    t0 = time.monotonic()
    with pytest.raises(InputError, match=rf"127\.0\.0\.1:{port}: nothing listens there \(connection refused\)"):
        check_scheduler(f"127.0.0.1:{port}")
    assert time.monotonic() - t0 < 1.0  # not after Dask's 10 s connect timeout


@pytest.mark.parametrize("address, expected", [
    ("tls://127.0.0.1:8786", "tls:// needs Dask's TLS settings"),
    ("ucx://127.0.0.1:8786", "ucx:// needs Dask's UCX transport"),
    ("inproc://127.0.0.1/1/2", "got inproc://"),
    ("tcp://:8786", "no host in the address"),
    ("tcp://127.0.0.1:99999", "port '99999' is not a number from 1 to 65535"),
    ("tcp://127.0.0.1:80a", "port '80a' is not a number"),
    ("tcp://no-such-host.invalid:8786", "cannot resolve host 'no-such-host.invalid'"),
])
def test_addresses_rigcal_cannot_use(address, expected):
    from rigcal.study.scale import check_scheduler

    with pytest.raises(InputError, match=expected.replace("(", r"\(").replace("+", r"\+")):
        check_scheduler(address)


def test_address_forms():
    from rigcal.study.scale import parse_scheduler_address

    assert parse_scheduler_address("tcp://10.0.0.5:8786") == ("tcp", "10.0.0.5", 8786)
    assert parse_scheduler_address("10.0.0.5:9000") == ("tcp", "10.0.0.5", 9000)
    assert parse_scheduler_address("tcp://node7") == ("tcp", "node7", 8786)
    assert parse_scheduler_address("tcp://[::1]:8786") == ("tcp", "::1", 8786)


@pytest.mark.parametrize("greeting", [pytest.param(None, marks=pytest.mark.slow), BANNER], ids=["silent", "banner"])
def test_batch_refuses_a_service_that_is_not_a_scheduler(cli, refused, fleet, tmp_path, greeting):
    """Was: the silent service hung for ever, the banner ended in "out of memory"."""
    out = tmp_path / "out"
    with fake_service(greeting) as port:
        t0 = time.monotonic()
        proc = cli("calibrate", "--batch", fleet / "car0", fleet / "car1", "--out", out,
                   "--scheduler", f"tcp://127.0.0.1:{port}", seconds=30)
        elapsed = time.monotonic() - t0
    refused(proc, f"--scheduler tcp://127.0.0.1:{port}", "not a Dask scheduler", code=1)
    assert elapsed < 14.0  # the probe's 4 s and the command's start (seconds on a loaded machine)
    assert not out.exists()


def test_batch_refuses_a_dead_address_at_once(cli, refused, fleet, tmp_path):
    """Was: refused only after Dask's 10 s connect timeout."""
    out = tmp_path / "out"
    port = _closed_port()
    t0 = time.monotonic()
    proc = cli("calibrate", "--batch", fleet / "car0", "--out", out, "--scheduler", f"tcp://127.0.0.1:{port}")
    refused(proc, f"127.0.0.1:{port}", "connection refused", code=1)
    assert time.monotonic() - t0 < 9.0  # Dask's connect timeout alone was 10 s
    assert not out.exists()


@pytest.mark.parametrize("address, expected", [
    ("tls://127.0.0.1:8786", "tls:// needs"), ("ucx://127.0.0.1:8786", "ucx:// needs"),
])
@pytest.mark.parametrize("command", ["batch", "prius", "mocap"])
def test_transports_are_one_line_before_any_work(cli, refused, fleet, tmp_path, address, expected, command):
    """Was: a TypeError traceback (tls, ucx)."""
    out = tmp_path / "out"
    argv = {"batch": ["calibrate", "--batch", fleet / "car0"],
            "prius": ["study", "prius", fleet / "car0" / "rig.yaml", "--table", "III", "--draws", "1"],
            "mocap": ["study", "mocap", "--trials", "2", "--measurements", "3"]}[command]
    refused(cli(*argv, "--out", out, "--scheduler", address, seconds=30), address, expected, code=1)
    assert not out.exists()


def test_study_refuses_a_banner_service_before_the_study(cli, refused, fleet, tmp_path):
    out = tmp_path / "out"
    with fake_service(BANNER) as port:
        proc = cli("study", "prius", fleet / "car0" / "rig.yaml", "--table", "III", "--draws", "1000",
                   "--out", out, "--scheduler", f"tcp://127.0.0.1:{port}", seconds=30)
    refused(proc, f"127.0.0.1:{port}", "not a Dask scheduler", code=1)
    assert not out.exists()


# ---------------------------------------------------------------------------------------------
# real Dask schedulers and workers, as processes


def _free_port() -> int:
    return _closed_port()


@contextmanager
def dask_processes(workers: int = 1):
    """A ``dask scheduler`` process on a free loopback port and ``workers`` ``dask worker``
    processes (one thread each); yields (address, scheduler process). Everything is killed
    after."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                               "--port", str(port), "--no-dashboard"], env=env, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
                break
            except OSError:
                assert time.monotonic() < deadline, "the scheduler did not start"
                time.sleep(0.2)
        for _ in range(workers):
            procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address,
                                           "--nthreads", "1", "--no-dashboard"], env=env,
                                          stderr=subprocess.DEVNULL))
        if workers:
            from distributed import Client

            with Client(address, timeout="10s") as client:
                client.wait_for_workers(workers, timeout=60)
        yield address, procs[0]
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait(10)


@pytest.mark.slow
def test_a_scheduler_without_workers_is_refused_within_seconds(cli, refused, fleet, tmp_path):
    """Was: a traceback, "TimeoutError: No valid workers found"."""
    from distributed import LocalCluster

    from rigcal.study.scale import NO_HTTP_PORT

    out = tmp_path / "out"
    with LocalCluster(n_workers=0, dashboard_address=None, scheduler_kwargs=NO_HTTP_PORT) as cluster:
        address = cluster.scheduler_address
        t0 = time.monotonic()
        proc = cli("calibrate", "--batch", fleet / "car0", fleet / "car1", "--out", out, "--scheduler", address,
                   seconds=60)
        elapsed = time.monotonic() - t0
    refused(proc, address, "has no worker (waited 5 s)", code=1)
    assert elapsed < 15.0  # the 5 s wait for a worker, the command's start
    assert not out.exists()


def _slow_square(pause_s: float, x: int) -> int:
    time.sleep(pause_s)
    return x * x


def _dies_once(marker: str, x: int) -> int:
    """x * 10; the worker running item 3 dies the first time (its process exits)."""
    if x == 3 and not os.path.exists(marker):
        Path(marker).write_text("died")
        os._exit(1)
    time.sleep(0.05)
    return 10 * x


def test_a_lost_worker_s_task_runs_again(dask_cluster, tmp_path):
    """A worker of the LocalCluster dies while it runs a task (its nanny starts a new one): the
    task runs again, every result arrives, none twice."""
    from rigcal.study.scale import task_runner

    marker = tmp_path / "died"
    got: list[int] = []
    with task_runner(dask_cluster.scheduler_address) as runner:
        report = runner.run_each(_dies_once, list(range(8)), shared=str(marker), on_result=lambda i, v: got.append(i),
                                 name="dies-once")
        assert runner.map(_dies_once, list(range(8)), shared=str(marker)) == [10 * x for x in range(8)]
    assert marker.read_text() == "died"
    assert report.missing == {} and report.lost is None
    assert sorted(got) == list(range(8))


@pytest.mark.slow
def test_a_lost_scheduler_keeps_what_finished_and_names_the_rest():
    """A real scheduler process killed after three results: they stay delivered, the others are
    missing with the reason; with finish_here the rest runs in this process instead."""
    from rigcal.study.scale import task_runner

    for finish_here in (False, True):
        with dask_processes(workers=1) as (address, scheduler):
            got: dict[int, int] = {}

            def arrived(i: int, value: int) -> None:
                got[i] = value
                if len(got) == 3:
                    scheduler.kill()

            t0 = time.monotonic()
            with task_runner(address) as runner:
                report = runner.run_each(_slow_square, list(range(12)), shared=0.3, on_result=arrived,
                                         finish_here=finish_here)
            assert time.monotonic() - t0 < 30
        assert report.lost and "scheduler" in report.lost
        assert all(v == i * i for i, v in got.items())
        if finish_here:
            assert sorted(got) == list(range(12)) and report.missing == {} and report.here >= 1
        else:
            assert len(got) >= 3 and report.missing and set(got) | set(report.missing) == set(range(12))
            assert not set(got) & set(report.missing)
            assert all(why == report.lost for why in report.missing.values())


@pytest.mark.slow
def test_batch_on_a_scheduler_that_dies_writes_what_finished(cli_start, fleet, tmp_path):
    """``calibrate --batch`` on a real scheduler with one worker; the scheduler is killed once the
    first dataset's folder is written: the finished datasets stay, complete; the run ends with
    one line naming the ones not calibrated, exit code 4."""
    out = tmp_path / "out"
    cars = [fleet / f"car{k}" for k in range(6)]
    with dask_processes(workers=1) as (address, scheduler):
        proc = cli_start("calibrate", "--batch", *cars, "--out", out, "--scheduler", address, "--cv-folds", "0")
        deadline = time.monotonic() + 120
        while not (out.is_dir() and any(p.is_dir() and not p.name.startswith(".") for p in out.iterdir())):
            assert time.monotonic() < deadline and proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        scheduler.kill()
        _, err = proc.communicate(timeout=120)
    err = err.decode()
    written = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    # the first result was written while the others still ran (one worker, about a second each)
    assert 1 <= len(written) < 6, (written, err)
    assert proc.returncode == 4, err
    assert "Traceback" not in err, err
    for name in written:
        assert {p.name for p in (out / name).iterdir()} >= {"calibration.yaml", "report.json", "report.html"}
    errors = [line for line in err.splitlines() if line.startswith("rigcal: error:")]
    assert len(errors) == 1, err
    missing = [f"car{k}" for k in range(6) if f"car{k}" not in written]
    assert "scheduler" in errors[0] and all(m in errors[0] for m in missing), errors[0]
    assert f"{len(written)} of 6 datasets written" in errors[0]


@pytest.fixture
def cli_start():
    def start(*args):
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
        return subprocess.Popen([sys.executable, "-m", "rigcal.cli.main", *map(str, args)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    return start


# ---------------------------------------------------------------------------------------------
# Ctrl-C and SIGTERM on a local cluster


@pytest.mark.slow
@pytest.mark.parametrize("sig, code, word", [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")])
def test_interrupted_local_cluster_batch_leaves_no_warning_and_no_process(cli_start_err, fleet, tmp_path, sig, code,
                                                                         word):
    """Was: a two-line leaked-semaphore warning from multiprocessing's resource tracker, and
    tracebacks from workers that outlived their scheduler."""
    psutil = pytest.importorskip("psutil")
    out = tmp_path / "out"
    proc = cli_start_err("calibrate", "--batch", *(fleet / f"car{k}" for k in range(6)), "--out", out,
                         "--scheduler", "local")
    parent = psutil.Process(proc.pid)
    deadline = time.monotonic() + 60
    children: list = []
    # the cluster is up: its two worker processes (and their nannies) run
    while len(children) < 3 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
        try:
            children = parent.children(recursive=True)
        except psutil.NoSuchProcess:
            break
    time.sleep(0.8)
    proc.send_signal(getattr(signal, sig))
    _, err = proc.communicate(timeout=60)
    err = err.decode()
    if proc.returncode == 0:
        pytest.skip("the batch finished before the signal")
    assert proc.returncode == code, err
    assert word in err and "leaked" not in err and "Traceback" not in err and "Warning" not in err, err
    _, alive = psutil.wait_procs(children, timeout=10)
    assert not alive, alive


@pytest.fixture
def cli_start_err():
    def start(*args):
        return subprocess.Popen([sys.executable, "-m", "rigcal.cli.main", *map(str, args)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return start
