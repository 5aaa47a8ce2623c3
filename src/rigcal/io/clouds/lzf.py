"""LZF, the codec of PCD ``binary_compressed`` data (see :mod:`rigcal.io.clouds`):
liblzf through ``python-neo-lzf`` when installed, else a pure-Python codec of the same format."""

from __future__ import annotations

from rigcal.errors import InputError

try:  # python-neo-lzf: liblzf, compiled
    import lzf as _clzf
except ImportError:  # pragma: no cover - the package is a dependency
    _clzf = None

LZF_BACKEND = "liblzf (python-neo-lzf)" if _clzf is not None else "pure Python"
"""Which LZF codec :func:`lzf_compress` / :func:`lzf_decompress` use."""

_LZF_MAX_RATIO = 88  # a 3-byte back reference yields at most 264 bytes


def lzf_decompress(data: bytes | bytearray | memoryview, expected_size: int | None = None,
                   source: str = "LZF data") -> bytes:
    """Decompress one LZF block; ``expected_size`` (if given) must match the output length, and
    no more than it is ever produced (a "bomb" stops there).

    Corrupt input (a reference before the start, a token cut short) raises InputError naming
    ``source``. With ``expected_size`` the compiled codec is used when installed."""
    src = bytes(data)
    n = len(src)
    if expected_size is not None:
        if expected_size > _LZF_MAX_RATIO * n:
            raise InputError(
                f"{source}: LZF data of {n} bytes cannot decompress to the announced "
                f"{expected_size} bytes (at most {_LZF_MAX_RATIO} x {n})"
            )
        if _clzf is not None:
            return _lzf_decompress_compiled(src, expected_size, source)
    out = bytearray()
    i = 0
    while i < n:
        ctrl = src[i]
        i += 1
        if ctrl < 32:  # literal run
            run = ctrl + 1
            if i + run > n:
                raise InputError(
                    f"{source}: corrupt LZF data: literal run of {run} bytes at input byte "
                    f"{i - 1} goes past the end ({n} bytes)"
                )
            out += src[i:i + run]
            i += run
            if expected_size is not None and len(out) > expected_size:
                break
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                raise InputError(f"{source}: corrupt LZF data: truncated back reference at end")
            length += src[i]
            i += 1
        if i >= n:
            raise InputError(f"{source}: corrupt LZF data: truncated back reference at end")
        distance = ((ctrl & 0x1F) << 8 | src[i]) + 1
        i += 1
        length += 2
        start = len(out) - distance
        if start < 0:
            raise InputError(
                f"{source}: corrupt LZF data: back reference {distance} bytes before output "
                f"byte {len(out)}"
            )
        if expected_size is not None and len(out) + length > expected_size:
            break  # reported below: more data than announced
        if distance >= length:
            out += out[start:start + length]
        else:  # overlapping copy repeats the last `distance` bytes
            pattern = bytes(out[start:])
            out += (pattern * (length // distance + 1))[:length]
    if expected_size is not None and (len(out) != expected_size or i < n):
        got = f"{len(out)} bytes" if i >= n else f"more than {expected_size} bytes"
        raise InputError(
            f"{source}: LZF data decompress to {got}, expected {expected_size}"
        )
    return bytes(out)


_LZF_MAX_DISTANCE = 1 << 13
_LZF_MAX_MATCH = 264
_LZF_MAX_LITERAL = 32


def _emit_literals(out: bytearray, chunk: bytes) -> None:
    for k in range(0, len(chunk), _LZF_MAX_LITERAL):
        part = chunk[k:k + _LZF_MAX_LITERAL]
        out.append(len(part) - 1)
        out += part


def _match_length(data: bytes, a: int, b: int, limit: int) -> int:
    """Length of the common prefix of data[a:] and data[b:], at most ``limit``."""
    length = 0
    step = 32
    while length + step <= limit and data[a + length:a + length + step] == data[
        b + length:b + length + step
    ]:
        length += step
    while length < limit and data[a + length] == data[b + length]:
        length += 1
    return length


def _lzf_decompress_compiled(src: bytes, expected_size: int, source: str) -> bytes:
    if expected_size == 0 or not src:
        if src or expected_size:
            got = "more than 0 bytes" if src else "0 bytes"
            raise InputError(f"{source}: LZF data decompress to {got}, expected {expected_size}")
        return b""
    try:
        out = _clzf.decompress(src, expected_size)
    except ValueError:
        raise InputError(
            f"{source}: corrupt LZF data (a back reference before the start of the output or a "
            "token cut short)"
        ) from None
    except MemoryError:
        raise InputError(
            f"{source}: not enough memory to decompress the announced {expected_size} bytes"
        ) from None
    if out is None:  # liblzf stops where the output would pass expected_size
        raise InputError(
            f"{source}: LZF data decompress to more than {expected_size} bytes, expected "
            f"{expected_size}"
        )
    if len(out) != expected_size:
        raise InputError(
            f"{source}: LZF data decompress to {len(out)} bytes, expected {expected_size}"
        )
    return out


def lzf_compress(data: bytes | bytearray | memoryview) -> bytes:
    """Compress ``data`` into one LZF block (liblzf when installed; otherwise greedy matching
    over a hash of 3-byte keys in pure Python, about a second per megabyte)."""
    src = bytes(data)
    n = len(src)
    if _clzf is not None and n:
        # incompressible data grow by at most 1 byte in 32 (a literal run's control byte)
        out = _clzf.compress(src, n + n // 16 + 64)
        if out is not None:
            return out
    out = bytearray()
    table: dict[bytes, int] = {}
    literal_start = 0
    i = 0
    while i + 2 < n:
        key = src[i:i + 3]
        candidate = table.get(key)
        table[key] = i
        if candidate is None or i - candidate > _LZF_MAX_DISTANCE:
            i += 1
            continue
        length = 3 + _match_length(src, candidate + 3, i + 3, min(_LZF_MAX_MATCH, n - i) - 3)
        _emit_literals(out, src[literal_start:i])
        code = length - 2
        offset = i - candidate - 1
        if code < 7:
            out.append((code << 5) | (offset >> 8))
        else:
            out.append((7 << 5) | (offset >> 8))
            out.append(code - 7)
        out.append(offset & 0xFF)
        end = i + length
        for j in range(max(i + 1, end - 2), min(end, n - 2)):  # keep the table fresh
            table[src[j:j + 3]] = j
        i = literal_start = end
    _emit_literals(out, src[literal_start:])
    return bytes(out)


# --------------------------------------------------------------------------------------------
