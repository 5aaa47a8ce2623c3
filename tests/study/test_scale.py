"""rigcal.study.scale and the Prius study on Dask: the same numbers as in-process, exactly."""

from __future__ import annotations

import json
import operator
import os
from pathlib import Path

import numpy as np
import pytest

from rigcal.cli.main import run
from rigcal.io.dataset.manifest import load_manifest
from rigcal.study import prius
from rigcal.study.scale import MAX_CHUNK, Runner, chunk_size, task_runner, worker_environment

MANIFEST = Path(__file__).resolve().parents[2] / "examples" / "prius" / "rig.yaml"
SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "tudelft_prius"


@pytest.fixture(scope="module")
def dataset():
    if not (SHARED / "detections" / "lidar.csv").is_file():
        pytest.skip("../shared/data (beside the repository) not present")
    return load_manifest(MANIFEST)


@pytest.fixture(scope="module")
def runner(dask_cluster):
    with task_runner(dask_cluster.scheduler_address) as r:
        yield r


def test_map_keeps_item_order_and_reports_progress(runner):
    seen = []
    out = runner.map(operator.add, list(range(20)), shared=100, progress=lambda d, t: seen.append((d, t)))
    assert out == [100 + i for i in range(20)]
    assert seen[0] == (0, 20) and seen[-1] == (20, 20) and len(seen) == 21
    assert "scheduler" in runner.description and runner.workers == 2
    assert Runner().map(operator.add, [1, 2], shared=1) == [2, 3]


def test_many_items_run_in_chunks_in_item_order(runner):
    # 2 workers x 50 chunks x 3: three items per Dask task, the last chunk short
    n = 2 * 50 * 3 + 2
    assert chunk_size(n, 2) == 3 and chunk_size(10, 2) == 1 and chunk_size(10**6, 2) == MAX_CHUNK
    seen = []
    out = runner.map(operator.mul, list(range(n)), shared=3, progress=lambda d, t: seen.append(d))
    assert out == [3 * i for i in range(n)]
    assert seen[0] == 0 and seen[-1] == n and seen == sorted(seen) and len(seen) == 1 + -(-n // 3)


def test_local_workers_run_blas_single_threaded_without_a_malloc_trim_threshold(runner):
    """The cluster's workers (tests/conftest.py builds it as task_runner does) get Dask's
    pre-spawn environment without MALLOC_TRIM_THRESHOLD_ (see worker_environment)."""
    names = ["MALLOC_TRIM_THRESHOLD_", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"]
    # os.getenv(name, default) runs in the worker: its environment, not this process's
    seen = [runner.map(os.getenv, ["unset"], shared=name)[0] for name in names]
    assert seen == ["unset", "1", "1"]
    assert "MALLOC_TRIM_THRESHOLD_" not in worker_environment()


def test_a_failing_task_raises_here(runner):
    with pytest.raises(ZeroDivisionError):
        runner.map(operator.truediv, [1, 0, 2], shared=1)


def test_table_iii_on_dask_equals_serial_exactly(dataset, runner):
    serial = prius.table_iii(dataset, draws=1, seed=3)
    dask = prius.table_iii(dataset, draws=1, seed=3, runner=runner)
    assert json.loads(prius.study_json(serial, {})) == json.loads(prius.study_json(dask, {}))  # exact


def test_fig8_on_dask_equals_serial_exactly(dataset, runner):
    serial = prius.fig8(dataset, draws=1, seed=3, sigmas_m=(0.0, 0.03))
    dask = prius.fig8(dataset, draws=1, seed=3, sigmas_m=(0.0, 0.03), runner=runner)
    assert json.loads(prius.study_json(serial, {})) == json.loads(prius.study_json(dask, {}))  # exact
    by = {(r.config, r.pair, r.sigma_m): r.median_mm for r in serial}
    assert by[("FCPE", "lidar1-camera1", 0.03)] != by[("FCPE", "lidar1-camera1", 0.0)]  # the noise moves it


def test_fig8_at_sigma_0_is_table_iii_on_the_same_sets(dataset):
    _, _, t3 = prius.table_iii_tasks(dataset, draws=4, seed=3)
    for sigma, (label, mode, ref), tasks in prius.fig8_tasks(dataset, draws=4, seed=3, sigmas_m=(0.0, 0.01)):
        same = [t for t in t3 if (t.mode, t.reference) == (mode, ref)]
        if sigma == 0:
            assert tasks == same
        else:
            assert [t.boards for t in tasks] == [t.boards for t in same]
            assert [t.noise_seed for t in tasks] == [(3, 8, i) for i in range(4)]


def test_fig8_noise_comes_from_seed_and_draw_only(dataset):
    a = prius.lidar_noise(dataset, (0, 8, 5))
    assert np.array_equal(a, prius.lidar_noise(dataset, (0, 8, 5)))
    assert not np.array_equal(a, prius.lidar_noise(dataset, (0, 8, 6)))
    noisy = prius.noisy_lidar(dataset, 0.01, (0, 8, 5))
    lidar = dataset.sensor("lidar1").points
    moved = noisy.sensor("lidar1").points - lidar
    ok = np.isfinite(moved)
    assert 0.007 < np.std(moved[ok]) < 0.013
    assert np.array_equal(noisy.sensor("camera1").points, dataset.sensor("camera1").points, equal_nan=True)


def test_cli_table_iii_on_a_scheduler_address_equals_serial(dataset, dask_cluster, tmp_path):
    outs = {}
    for scheduler in ("serial", dask_cluster.scheduler_address):
        out = tmp_path / scheduler.replace("/", "_").replace(":", "_")
        assert run(["study", "prius", str(MANIFEST), "--table", "III", "--draws", "1",
                    "--scheduler", scheduler, "--out", str(out)]) == 0
        outs[scheduler] = json.loads((out / "study.json").read_text())
    assert outs["serial"]["rows"] == outs[dask_cluster.scheduler_address]["rows"]
    assert len(outs["serial"]["rows"]) == 15
    assert outs["serial"]["meta"]["scheduler"] == "serial"


@pytest.mark.slow
def test_cli_fig7_on_a_scheduler_address_equals_serial(dataset, dask_cluster, tmp_path):
    outs = {}
    for name, scheduler in (("serial", "serial"), ("dask", dask_cluster.scheduler_address)):
        out = tmp_path / name
        assert run(["study", "prius", str(MANIFEST), "--table", "fig7", "--draws", "1", "--seed", "2",
                    "--scheduler", scheduler, "--out", str(out)]) == 0
        outs[name] = json.loads((out / "study.json").read_text())
        assert (out / "fig7.png").stat().st_size > 10_000
    assert outs["serial"]["rows"] == outs["dask"]["rows"]
    assert outs["dask"]["meta"]["scheduler"].startswith("Dask scheduler tcp://")
    rows = outs["serial"]["rows"]
    assert {r["k"] for r in rows} == set(range(3, 30))
    assert {r["config"] for r in rows} == {"MCPE(lidar)", "PSE", "FCPE"}
    assert all("sigma_m" not in r and r["table"] == "fig7" and r["draws"] == 1 for r in rows)


def test_mocap_study_on_dask_equals_serial(runner, tmp_path):
    from rigcal.study.mocap_study import run_mocap_study, study_document

    kwargs = dict(target="diamond", sensor="lidar", measurements=(3,), trials=2, seed=5)
    serial = study_document(run_mocap_study(**kwargs))
    dask = study_document(run_mocap_study(**kwargs, runner=runner), runner.description)
    assert serial["rows"] == dask["rows"] and serial["trials"] == dask["trials"]  # exact
    assert dask["meta"]["scheduler"].startswith("Dask")
    assert {r["metric"] for r in serial["rows"]} == {"translation_mm", "rotation_deg", "translation_norm_diff_mm",
                                                    "rotation_angle_diff_deg", "residual"}
    row = next(r for r in serial["rows"] if r["metric"] == "translation_norm_diff_mm")
    assert row["table"] == "mocap Table I" and row["paper_mean"] is None  # the paper has N = 5, 15, 30
    assert row["n"] + row["failures"] == 2 and row["trials"] == 2
    assert [t["trial"] for t in serial["trials"]] == [0, 1]
    assert serial["meta"]["scheduler"] == "serial"


def test_run_each_delivers_every_result_once_with_its_index(runner):
    from rigcal.study.scale import MapReport

    for r in (Runner(), runner):
        got: dict[int, int] = {}
        report = r.run_each(operator.mul, list(range(30)), shared=7, on_result=lambda i, v: got.setdefault(i, v))
        assert got == {i: 7 * i for i in range(30)}
        assert report == MapReport({})
