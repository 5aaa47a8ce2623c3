"""Harness of the hostile-input suite: every case runs under a memory and a time limit.

``cli(*args)`` runs ``rigcal`` in a subprocess (address space and wall time limited) and returns
the finished process; ``refused(proc, *names)`` asserts the contract for a bad input: exit code
not 0, no traceback or warning, exactly one ``rigcal: error:`` line naming every one of ``names``.
``limited(fn)`` runs ``fn`` (e.g. a hypothesis test) in a forked child under the same limits, so
a parser that hangs or balloons fails the test instead of taking the machine down.
"""

from __future__ import annotations

import os
import re
import resource
import signal
import subprocess
import sys
import traceback
from pathlib import Path

import pytest

CLI_MEMORY_MB = 1536
# "rigcal: error: ..." for a bad input; "rigcal demo: error: ..." for argparse's usage errors
_ERROR_LINE = re.compile(r"^rigcal( [a-z]+)*: error: ")
CLI_SECONDS = 90


def _limit_child(memory_mb: int) -> None:
    limit = memory_mb << 20
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def run_cli(*args: str, cwd: Path | None = None, memory_mb: int = CLI_MEMORY_MB,
            seconds: float = CLI_SECONDS, stdin: bytes | None = None,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    full_env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                "PYTHONWARNINGS": "default", **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "rigcal.cli.main", *map(str, args)],
        cwd=cwd, input=stdin, capture_output=True, timeout=seconds, env=full_env,
        preexec_fn=lambda: _limit_child(memory_mb),
    )


def assert_refused(proc: subprocess.CompletedProcess, *names: str, code: int | None = None) -> str:
    """The one error line of a refused input (asserted as described in the module docstring)."""
    err = proc.stderr.decode("utf-8", "replace") if isinstance(proc.stderr, bytes) else proc.stderr
    assert proc.returncode != 0, f"accepted a bad input:\n{err}"
    if code is not None:
        assert proc.returncode == code, err
    assert "Traceback" not in err, err
    assert "Warning" not in err, err
    errors = [line for line in err.splitlines() if _ERROR_LINE.match(line)]
    assert len(errors) == 1, err
    for name in names:
        assert str(name) in errors[0], f"{name!r} not named in: {errors[0]}"
    return errors[0]


def _vm_bytes() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmSize:"):
            return int(line.split()[1]) * 1024
    return 0


def run_limited(fn, memory_mb: int = 1024, seconds: int = 120) -> None:
    """Run ``fn()`` in a forked child with ``memory_mb`` more address space than this process
    and ``seconds`` of wall time; a failure, a hang or a memory blow-up fails the calling test."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child
        os.close(r)
        code, message = 0, b""
        try:
            limit = _vm_bytes() + (memory_mb << 20)
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
            signal.alarm(seconds)
            fn()
        except BaseException:  # noqa: BLE001 - reported to the parent
            code, message = 1, traceback.format_exc().encode("utf-8", "replace")
        try:
            os.write(w, message[-30000:])
        finally:
            os._exit(code)
    os.close(w)
    chunks = []
    while chunk := os.read(r, 65536):
        chunks.append(chunk)
    os.close(r)
    _, status = os.waitpid(pid, 0)
    text = b"".join(chunks).decode("utf-8", "replace")
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        why = "took longer than %d s" % seconds if sig == signal.SIGALRM else f"killed by signal {sig}"
        pytest.fail(f"{getattr(fn, '__name__', fn)} {why} (memory limit {memory_mb} MiB)\n{text}")
    if os.WEXITSTATUS(status) != 0:
        pytest.fail(text)


@pytest.fixture
def cli():
    return run_cli


@pytest.fixture
def refused():
    return assert_refused


@pytest.fixture
def limited():
    if not hasattr(os, "fork"):
        pytest.skip("needs os.fork to run each case under a memory limit")
    return run_limited


# ---------------------------------------------------------------------------------------------
# fuzzing: valid files mutated the way broken and hostile files differ from good ones

_NASTY_NUMBERS = ["nan", "NaN", "inf", "-inf", "1.797e308", "1e309", "-1e400", "4.9e-324",
                  "9" * 40, "0x1p5", "", "-", "1e", "0", "-0"]


def mutated_text(seed: str):
    """A hypothesis strategy: ``seed`` with a few edits (number swapped for a nasty one, bytes
    flipped, lines dropped or repeated, truncation, CR-only or mixed line endings)."""
    from hypothesis import strategies as st

    def edit(text: str, op: int, k: int, nasty: str) -> str:
        if not text:
            return nasty
        i = k % len(text)
        if op == 0:  # replace the number at/after i
            m = re.compile(r"-?\d+(\.\d+)?([eE][-+]?\d+)?").search(text, i) or re.search(r"\d+", text)
            return text if m is None else text[:m.start()] + nasty + text[m.end():]
        if op == 1:
            return text[:i]
        if op == 2:
            return text[:i] + chr((ord(text[i]) ^ (1 << (k % 7))) or 1) + text[i + 1:]
        lines = text.split("\n")
        j = k % len(lines)
        if op == 3:
            return "\n".join(lines[:j] + lines[j + 1:])
        if op == 4:
            return "\n".join(lines[:j] + [lines[j]] * 3 + lines[j:])
        if op == 5:
            return text.replace("\n", "\r")
        return text[:i] + nasty + text[i:]

    ops = st.lists(st.tuples(st.integers(0, 6), st.integers(0, 1 << 30), st.sampled_from(_NASTY_NUMBERS)),
                   min_size=1, max_size=4)
    return ops.map(lambda steps: _apply(seed, steps, edit))


def _apply(seed, steps, edit):
    text = seed
    for op, k, nasty in steps:
        text = edit(text, op, k, nasty)
    return text


@pytest.fixture
def mutations():
    return mutated_text
