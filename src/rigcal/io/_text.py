"""Private helpers shared by the readers: reading text files and loading YAML with context."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import yaml

from rigcal.errors import InputError
from rigcal.io.limits import MAX_BYTES, YAML_MAX_DEPTH, YAML_MAX_NODES, MiB, read_limited

_BaseLoader: type = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _StrictLoader(_BaseLoader):  # type: ignore[misc, valid-type]
    """A safe loader that refuses duplicate mapping keys (PyYAML silently keeps the last)."""


def _construct_mapping(loader: Any, node: yaml.MappingNode, deep: bool = False) -> dict:
    # duplicates are looked for among the keys written in this mapping; keys brought in by a
    # merge key (``<<: *base``) may be overridden by explicit ones, as YAML specifies
    seen: set[Any] = set()
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue
        key = loader.construct_object(key_node, deep=True)
        try:
            duplicate = key in seen
            seen.add(key)
        except TypeError:  # unhashable key: the base constructor reports it
            continue
        if duplicate:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark
            )
    loader.flatten_mapping(node)
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


_StrictLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping
)


def _expanded_size(node: yaml.Node, memo: dict[int, int], depth: int, source: str) -> int:
    """Nodes in ``node`` with every alias expanded (shared sub-graphs counted once per use)."""
    key = id(node)
    if key in memo:
        return memo[key]
    if depth > YAML_MAX_DEPTH:
        raise InputError(
            f"{source}: YAML nested deeper than {YAML_MAX_DEPTH} levels (or an alias refers to "
            "itself); expected a plain configuration document"
        )
    if isinstance(node, yaml.SequenceNode):
        n = 1 + sum(_expanded_size(c, memo, depth + 1, source) for c in node.value)
    elif isinstance(node, yaml.MappingNode):
        n = 1 + sum(
            _expanded_size(k, memo, depth + 1, source) + _expanded_size(v, memo, depth + 1, source)
            for k, v in node.value
        )
    else:
        n = 1
    if n > YAML_MAX_NODES:
        raise InputError(
            f"{source}: YAML expands to more than {YAML_MAX_NODES:,} values (aliases such as "
            "*name repeat their anchor's content); expected a configuration of ordinary size"
        )
    memo[key] = n
    return n


def load_yaml(text: str, source: str) -> Any:
    """Parse YAML ``text`` (safe, duplicate keys refused, merge keys allowed); errors name
    ``source`` and the line. Documents that expand (through aliases) to more than
    :data:`~rigcal.io.limits.YAML_MAX_NODES` values or nest deeper than
    :data:`~rigcal.io.limits.YAML_MAX_DEPTH` are refused before they are built."""
    if len(text) > MAX_BYTES["yaml"]:
        raise InputError(f"{source}: YAML text is larger than {MAX_BYTES['yaml'] // MiB} MiB")
    loader = _StrictLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node, {}, 0, source)
        return loader.construct_document(node)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = " ".join(str(exc.problem or exc.context or "syntax error").split())
        raise InputError(f"{source}: {where}invalid YAML: {problem}") from None
    except yaml.YAMLError as exc:
        detail = " ".join(str(exc).split())
        raise InputError(f"{source}: invalid YAML: {detail}") from None
    except RecursionError:
        raise InputError(
            f"{source}: YAML nested too deeply; expected a plain configuration document"
        ) from None
    except (ValueError, OverflowError) as exc:
        # a value the constructor cannot build: an integer of more than 4300 digits (Python's
        # conversion limit), a date such as 2024-13-45
        detail = " ".join(str(exc).split())
        if "integer string conversion" in detail:
            import re

            digits = re.search(r"value has (\d+) digits", detail)
            detail = (f"an integer of {digits.group(1) if digits else 'more than 4300'} digits (at most 4300 "
                      "are read); expected numbers of ordinary size")
        raise InputError(f"{source}: invalid YAML value: {detail[:200]}") from None
    finally:
        loader.dispose()


def load_json(text: str, source: str, max_depth: int = YAML_MAX_DEPTH) -> Any:
    """Parse JSON ``text``; InputError naming ``source`` for invalid JSON (with the line), an
    integer of more digits than Python converts (4300), nesting deeper than ``max_depth``
    (checked after parsing, without recursion, so later code may walk the value)."""
    import json

    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{source}: not valid JSON (line {exc.lineno}: {exc.msg})") from None
    except ValueError as exc:  # "Exceeds the limit (4300 digits) for integer string conversion"
        raise InputError(f"{source}: not a usable JSON document ({exc})") from None
    except RecursionError:
        raise InputError(f"{source}: JSON nested too deeply (more than {max_depth} levels expected at most)") from None
    stack = [(data, 0)]
    while stack:
        value, depth = stack.pop()
        if isinstance(value, (dict, list)):
            if depth >= max_depth:
                raise InputError(f"{source}: JSON nested more than {max_depth} levels deep")
            stack.extend((v, depth + 1) for v in (value.values() if isinstance(value, dict) else value))
    return data


#: libyaml's emitter when PyYAML was built with it (about 5x faster), else the pure-Python one
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def dump_yaml(data: Any, flow: bool | None = False) -> str:
    """``data`` as YAML in field order, unwrapped lines, Unicode kept; ``flow``: PyYAML's
    ``default_flow_style`` (False: block style; None: flow for leaf collections)."""
    return yaml.dump(
        data, Dumper=_DUMPER, sort_keys=False, default_flow_style=flow, allow_unicode=True,
        width=10_000,
    )


def json_safe(value: Any) -> Any:
    """``value`` with NaN and infinities as None (strict JSON), mapping keys as strings."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def read_text(path: str | os.PathLike[str], what: str = "file") -> str:
    """The UTF-8 text of ``path``; a missing, unreadable, binary, oversized or non-regular file
    (directory, FIFO, device) raises InputError. See :mod:`rigcal.io.limits`."""
    data = read_limited(path, what, "text")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{Path(path)}: {what} is not UTF-8 text (byte {exc.start}: {exc.reason})"
        ) from None


def is_number(value: Any) -> bool:
    """True for int/float values that are not bools."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def is_finite_number(value: Any) -> bool:
    return is_number(value) and math.isfinite(value)


def type_name(value: Any) -> str:
    """A YAML-ish name of a parsed value's type, for messages."""
    if value is None:
        return "nothing (null)"
    return {
        bool: "a boolean",
        int: "an integer",
        float: "a number",
        str: "a string",
        list: "a list",
        dict: "a mapping",
    }.get(type(value), type(value).__name__)


def check_keys(value: Mapping[Any, Any], allowed: Sequence[str], where: str) -> None:
    """InputError naming every key of ``value`` that is not in ``allowed`` (and the allowed)."""
    unknown = [str(k) for k in value if k not in allowed]
    if unknown:
        raise InputError(
            f"{where}: unknown key(s) {', '.join(repr(k) for k in unknown)} "
            f"(allowed: {', '.join(allowed)})"
        )


def nonempty_string(value: Any, where: str) -> str:
    """``value`` if it is a string with more than white space in it; else InputError."""
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"{where}: expected a non-empty string, got {type_name(value)} {value!r}")
    return value
