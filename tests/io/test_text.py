"""rigcal.io._text.load_json: JSON errors name the file (syntax, 5000-digit integers, nesting)."""

from __future__ import annotations

import pytest

from rigcal.errors import InputError, printable
from rigcal.io._text import load_json


@pytest.mark.parametrize("text, match", [
    ("{not json", r"r\.json: not valid JSON \(line 1: Expecting property name"),
    ('{"n": ' + "9" * 5000 + "}", r"r\.json: not a usable JSON document \(Exceeds the limit \(4300 digits\)"),
    ("[" * 100000 + "]" * 100000, r"r\.json: JSON nested too deeply"),
    ('{"a": ' * 65 + "1" + "}" * 65, r"r\.json: JSON nested more than 64 levels deep"),
])
def test_load_json_refusals(text, match):
    with pytest.raises(InputError, match=match):
        load_json(text, "r.json")


def test_load_json_values():
    assert load_json('{"a": [1, {"b": null}], "c": 1e999}', "r.json") == {"a": [1, {"b": None}], "c": float("inf")}
    deep = '{"a": ' * 63 + "1" + "}" * 63
    assert load_json(deep, "r.json")


def test_printable_escapes_control_characters_only():
    assert printable("car\n1\ttab\r\x00\x1b\u2028 é 日本 ok") == "car\\n1\\ttab\\r\\x00\\x1b\\u2028 é 日本 ok"
    assert printable(ValueError("a\nb")) == "a\\nb"


@pytest.mark.parametrize("loader", ["rigcal.io.config.vicon_json:load_json", "rigcal.io.config.camchain:_load_json"])
@pytest.mark.parametrize("text, match", [('{"a": ' + "9" * 5000 + "}", "4300 digits"), ("[" * 100000, "nested too deeply")])
def test_the_other_json_readers_name_the_file_too(loader, text, match):
    import importlib

    module, name = loader.split(":")
    with pytest.raises(InputError, match=rf"x\.json: .*{match}"):
        getattr(importlib.import_module(module), name)(text, "x.json")
