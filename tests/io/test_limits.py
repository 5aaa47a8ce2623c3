"""rigcal.io.limits and the YAML budget in rigcal.io._text: the one place input limits live."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io import limits
from rigcal.io._text import load_yaml, read_text


def test_regular_file_refuses_non_regular_files(tmp_path):
    with pytest.raises(InputError, match="directory"):
        limits.regular_file(tmp_path, "manifest")
    with pytest.raises(InputError, match="not found"):
        limits.regular_file(tmp_path / "missing.yaml", "manifest")
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp_path / "fifo")
        with pytest.raises(InputError, match="FIFO"):
            read_text(tmp_path / "fifo", "manifest")  # refused without opening (would block)
    if os.path.exists("/dev/null"):
        with pytest.raises(InputError, match="character device"):
            limits.read_limited("/dev/null", "scan", "point cloud")
    with pytest.raises(InputError, match="file name too long"):
        limits.regular_file(tmp_path / ("x" * 400), "manifest")


def test_size_budget(tmp_path, monkeypatch):
    p = tmp_path / "big.csv"
    p.write_bytes(b"0" * 2048)
    monkeypatch.setitem(limits.__dict__, "MAX_BYTES", {"text": 1024})
    with pytest.raises(InputError, match="big.csv.*more than"):
        limits.read_limited(p, "detection CSV")


def test_check_finite_names_field_index_and_unit():
    with pytest.raises(InputError, match=r"lidar.csv: x\[2\] is 1.797e\+308, expected a finite value within ±100000 m"):
        limits.check_finite([0.0, 1.0, 1.797e308], "lidar.csv", "x", "m")
    with pytest.raises(InputError, match=r"u\[0, 1\] is inf"):
        limits.check_finite([[1.0, np.inf]], "cam.csv", "u", "px")
    a = np.array([1.0, np.nan])
    out = limits.check_finite(a, "s", "x", allow_nan=True)
    assert np.isnan(out[1]) and a.flags.writeable  # input untouched
    with pytest.raises(InputError, match="nan"):
        limits.check_finite(a, "s", "x")
    assert limits.check_scalar("2.5", "rig.yaml", "windows_s[0]", "s") == 2.5
    with pytest.raises(InputError, match="windows_s"):
        limits.check_scalar(float("nan"), "rig.yaml", "windows_s[0]", "s")


def test_yaml_alias_bomb_is_refused_quickly():
    doc = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [" + ", ".join([f"*{p}"] * 9) + "]\n" for p, c in zip("abcdefgh", "bcdefghi")
    )
    with pytest.raises(InputError, match="bomb.yaml: YAML expands to more than"):
        load_yaml(doc, "bomb.yaml")


def test_yaml_aliases_of_ordinary_size_are_fine():
    assert load_yaml("a: &a [1, 2]\nb: *a\n", "s") == {"a": [1, 2], "b": [1, 2]}


@pytest.mark.parametrize("doc", ["a: &a [*a]\n", "[" * 200 + "]" * 200, "{a: " * 3000 + "1" + "}" * 3000])
def test_yaml_self_reference_and_deep_nesting_refused(doc):
    with pytest.raises(InputError, match="deep|nest"):
        load_yaml(doc, "deep.yaml")


def test_yaml_merge_keys_follow_the_standard():
    doc = "base: &b {x: 1, y: 2}\nd:\n  <<: *b\n  y: 3\ne:\n  <<: [*b, {z: 4}]\n"
    assert load_yaml(doc, "s") == {"base": {"x": 1, "y": 2}, "d": {"x": 1, "y": 3},
                                   "e": {"x": 1, "y": 2, "z": 4}}
    with pytest.raises(InputError, match="duplicate key 'y'"):
        load_yaml("d:\n  <<: {x: 1}\n  y: 3\n  y: 4\n", "s")
