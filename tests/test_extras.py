"""Optional parts behind pip extras (rigcal.extras): a command that needs a missing one says which
extra installs it in one line (exit 1, nothing written), and the base install's commands run
without any of them."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rigcal.cli.main import run
from rigcal.extras import EXTRAS, MissingExtraError, missing_extra_message, require
from rigcal.io.dataset.manifest import write_dataset
from rigcal.sim.rig import make_rig_placements, prius_like_rig, simulate

ROOT = Path(__file__).resolve().parents[1]
OPTIONAL = sorted(EXTRAS)


def _block(monkeypatch, *modules: str) -> None:
    """Make ``import MODULE`` fail as if the package were not installed."""
    for name in modules:
        monkeypatch.setitem(sys.modules, name, None)


@pytest.fixture(scope="module")
def manifest_dir(tmp_path_factory) -> Path:
    rng = np.random.default_rng(5)
    sensors = prius_like_rig()
    sim = simulate(sensors, make_rig_placements(rng, sensors, 8, min_fraction=1.0), rng=rng)
    return write_dataset(sim.dataset, tmp_path_factory.mktemp("data"))


def _one_line(err: str, extra: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("rigcal: error: "), err
    assert f'pip install "rigcal[{extra}]"' in lines[0] and "Traceback" not in err


def test_every_optional_module_names_the_pyproject_extra_that_installs_it():
    pyproject = (ROOT / "pyproject.toml").read_text()
    for module, extra in EXTRAS.items():
        assert f"\n{extra.extra} = [" in pyproject, extra
        line = next(ln for ln in pyproject.splitlines() if ln.startswith(f"{extra.extra} = ["))
        assert extra.package.split("[")[0] in line, (module, line)
    assert 'all = ["rigcal[images,plots,fleet,mcap]"]' in pyproject
    assert '"rigcal[all]"' in pyproject.split("test = [")[1]  # `.[test]` installs every extra


@pytest.mark.parametrize("module", OPTIONAL)
def test_require_names_the_extra(monkeypatch, module):
    _block(monkeypatch, module)
    extra = EXTRAS[module]
    expected = (f'doing X needs {extra.package}, which is not installed: pip install "rigcal[{extra.extra}]" '
                '(or "rigcal[all]")')
    with pytest.raises(MissingExtraError, match=f"^{re.escape(expected)}$"):
        require(module, "doing X")


def test_require_returns_the_module_and_lets_other_import_errors_through(monkeypatch):
    assert require("cv2", "x").__name__ == "cv2"
    assert missing_extra_message("numpy") is None and missing_extra_message("cv2.dnn") is not None
    with pytest.raises(ModuleNotFoundError):
        require("rigcal_no_such_module", "x")


def test_the_raw_demo_without_opencv(monkeypatch, tmp_path, capsys):
    _block(monkeypatch, "cv2")
    assert run(["demo", "--out", str(tmp_path / "d")]) == 1
    _one_line(capsys.readouterr().err, "images")
    assert not (tmp_path / "d").exists()


def test_calibrate_plot_without_matplotlib(monkeypatch, tmp_path, manifest_dir, capsys):
    _block(monkeypatch, "matplotlib")
    assert run(["calibrate", str(manifest_dir), "--plot", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    _one_line(err, "plots")
    assert "--plot" in err and not (tmp_path / "r").exists()


def test_a_dask_cluster_without_dask(monkeypatch, tmp_path, manifest_dir, capsys):
    import shutil

    cars = [shutil.copytree(manifest_dir.parent, tmp_path / name) for name in ("car01", "car02")]
    _block(monkeypatch, "distributed")
    code = run(["calibrate", "--batch", *map(str, cars), "--scheduler", "local", "--out", str(tmp_path / "b")])
    assert code == 1
    err = capsys.readouterr().err
    _one_line(err, "fleet")
    assert "--scheduler serial" in err and not (tmp_path / "b").exists()


def test_an_optional_import_deep_inside_a_command_is_the_same_one_line(monkeypatch, tmp_path, capsys):
    """Wherever a command imports a missing optional module without an early check, the command
    line names the extra (here: the export command raising it)."""
    from rigcal.cli import export

    def needs_opencv(args, console):
        import cv2  # noqa: F401

    _block(monkeypatch, "cv2")
    monkeypatch.setattr(export, "run", needs_opencv)
    assert run(["export", str(tmp_path / "c.yaml"), "--format", "yaml"]) == 1
    err = capsys.readouterr().err
    _one_line(err, "images")
    assert "'rigcal export' needs opencv-python-headless" in err


def test_a_missing_module_that_is_not_optional_is_not_disguised(monkeypatch, tmp_path):
    from rigcal.cli import export

    def broken(args, console):
        import rigcal_no_such_module  # noqa: F401

    monkeypatch.setattr(export, "run", broken)
    with pytest.raises(ModuleNotFoundError, match="rigcal_no_such_module"):
        run(["export", str(tmp_path / "c.yaml"), "--format", "yaml"])


BASE_ONLY = """
import sys
for name in {blocked!r}:
    sys.modules[name] = None
from rigcal.cli.main import run
sys.exit(run(sys.argv[1:]))
"""


def test_the_base_install_calibrates_and_writes_report_html(tmp_path, manifest_dir):
    """Without any extra (their modules made unimportable in a fresh interpreter): the
    detections demo, calibrate and export write their files, report.html with plotly.js."""
    script = BASE_ONLY.format(blocked=OPTIONAL)
    env = {**os.environ, "COLUMNS": "100"}

    def cli(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-c", script, *argv], capture_output=True, text=True,
                              env=env, timeout=300)

    demo = cli("demo", "--detections-only", "--boards", "8", "--out", str(tmp_path / "demo"))
    assert demo.returncode == 0, demo.stderr
    assert (tmp_path / "demo" / "fcpe" / "report.html").is_file()
    assert not (tmp_path / "demo" / "fcpe" / "calibration.png").exists()  # matplotlib: plots extra
    cal = cli("calibrate", str(manifest_dir), "--out", str(tmp_path / "r"))
    assert cal.returncode == 0, cal.stderr
    page = (tmp_path / "r" / "report.html").read_text()
    assert "plotly.js v" in page and len(page.encode()) <= 2_000_000
    exp = cli("export", str(tmp_path / "r" / "calibration.yaml"), "--format", "ros2-run")
    assert exp.returncode == 0 and "static_transform_publisher" in exp.stdout, exp.stderr
