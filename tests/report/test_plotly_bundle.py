"""The plotly.js partial build shipped in rigcal's package (src/rigcal/report/js/): committed, with
the licenses of what it bundles, and rebuilt byte for byte from the pinned tools/plotly-bundle."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from rigcal.report.page import BUNDLE, BUNDLE_TRACES, plotly_js

ROOT = Path(__file__).resolve().parents[2]
TOOL = ROOT / "tools" / "plotly-bundle"
LICENSES = BUNDLE.with_name(BUNDLE.name + ".LICENSE.txt")
#: what a page may weigh (issue 24): plotly.js is most of it
PAGE_LIMIT_BYTES = 2_000_000


def _pinned_plotly_version() -> str:
    return json.loads((TOOL / "package.json").read_text())["devDependencies"]["plotly.js"]


def test_the_bundle_is_package_data_of_the_pinned_version_with_its_licenses():
    text, version = plotly_js()
    assert version == _pinned_plotly_version()
    assert BUNDLE.stat().st_size < PAGE_LIMIT_BYTES - 150_000  # room for a page's data
    licenses = LICENSES.read_text(encoding="utf-8")
    assert f"plotly.js@{version} (license: \"MIT\")" in licenses
    assert "Copyright (c)" in licenses and "Permission is hereby granted" in licenses
    assert "plotly-rigcal.min.js.LICENSE.txt" in text[:600]  # the bundle's header points at them
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert '"js/*.js"' in pyproject and '"js/*.txt"' in pyproject  # both go into the wheel


def test_entry_js_registers_exactly_the_trace_types_the_pages_may_draw():
    entry = (TOOL / "entry.js").read_text()
    registered = set(re.findall(r"require\('plotly\.js/lib/(\w+)'\)", entry)) - {"core"}
    assert registered | {"scatter"} == BUNDLE_TRACES


def test_rigcal_does_not_depend_on_the_plotly_python_package():
    deps = (ROOT / "pyproject.toml").read_text().split("[project.optional-dependencies]")[0]
    assert not re.search(r'"plotly\b', deps)


@pytest.mark.slow
def test_the_committed_bundle_rebuilds_identically_from_the_pinned_lockfile(tmp_path):
    """npm ci of tools/plotly-bundle's lockfile (from the npm registry), then its build into a
    temporary folder: the same bytes as the committed bundle and license file."""
    if shutil.which("npm") is None or shutil.which("node") is None:
        pytest.skip("node/npm not found: cannot rebuild the plotly.js bundle")
    work = tmp_path / "plotly-bundle"
    work.mkdir()
    for name in ("package.json", "package-lock.json", "entry.js", "build.js"):
        shutil.copy2(TOOL / name, work / name)
    ci = subprocess.run(["npm", "ci", "--no-audit", "--no-fund", "--loglevel=error"], cwd=work,
                        capture_output=True, text=True, timeout=600)
    if ci.returncode != 0:
        pytest.skip(f"npm ci could not install the pinned packages (registry unreachable?): {ci.stderr[-400:]}")
    out = tmp_path / "plotly-rigcal.min.js"
    build = subprocess.run(["node", "build.js", str(out)], cwd=work, capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    assert out.read_bytes() == BUNDLE.read_bytes(), "the committed bundle differs from its rebuild: `make plotly-bundle`"
    assert out.with_name(out.name + ".LICENSE.txt").read_bytes() == LICENSES.read_bytes()
