"""Explicit state in files that run no code when read: a JSON tree beside a NumPy ``.npz``.

Checkpoints keep what a run depends on (env copies, counters, random streams) as plain values:
numbers, strings, lists, tuples, sets, dicts, deques, NumPy arrays and scalars, NumPy
``Generator`` s (their ``bit_generator.state``, a dict of ints) and CPU tensors. :func:`encode`
turns such a value into a JSON tree whose arrays are references into a dict of arrays;
:func:`decode` rebuilds it. The arrays are written with :func:`numpy.savez` and read with
``allow_pickle=False``, so neither file can hold anything but data: an object array, an unknown
marker or a bit generator NumPy does not ship is refused, never imported or called.
"""

from __future__ import annotations

import io
import json
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.files import atomic_path, write_atomic

#: The bit generators a saved ``Generator`` may name (looked up in ``numpy.random``, nothing else).
BIT_GENERATORS = ("PCG64", "PCG64DXSM", "MT19937", "Philox", "SFC64")


class StateFormatError(InputError):
    """A state file holds something that is not plain state."""


def encode(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    """``value`` as a JSON-able tree; its arrays are added to ``arrays`` (named ``a0``, ``a1`` ...).

    :raises StateFormatError: for a value of any other type (the caller's state is not plain).
    """
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)) and type(value) in (int, float):
        return value
    if isinstance(value, (np.ndarray, np.generic)):
        if isinstance(value, np.ndarray) and value.dtype == object:
            raise StateFormatError("an object array is not plain state")
        key = f"a{len(arrays)}"
        arrays[key] = np.asarray(value)
        return {"__array__": key, "scalar": isinstance(value, np.generic)}
    if isinstance(value, np.random.Generator):
        return {"__generator__": value.bit_generator.state}
    if type(value).__module__ == "torch" and type(value).__name__ == "Tensor":
        key = f"a{len(arrays)}"
        arrays[key] = value.detach().cpu().numpy()
        return {"__tensor__": key}
    if isinstance(value, deque):
        return {"__deque__": [encode(v, arrays) for v in value], "maxlen": value.maxlen}
    if isinstance(value, tuple):
        return {"__tuple__": [encode(v, arrays) for v in value]}
    if isinstance(value, (set, frozenset)):
        return {"__set__": [encode(v, arrays) for v in sorted(value)], "frozen": isinstance(value, frozenset)}
    if isinstance(value, list):
        return [encode(v, arrays) for v in value]
    if isinstance(value, dict):
        # Pairs, not a JSON object: keys may be ints, and no key can pass for a marker.
        return {"__dict__": [[encode(k, arrays), encode(v, arrays)] for k, v in value.items()]}
    raise StateFormatError(f"a {type(value).__name__} is not plain state")


def decode(tree: Any, arrays: dict[str, np.ndarray]) -> Any:
    """The value :func:`encode` turned into ``tree`` (arrays are fresh, writeable copies).

    :raises StateFormatError: for a tree :func:`encode` cannot have written.
    """
    if tree is None or isinstance(tree, (bool, int, float, str)):
        return tree
    if isinstance(tree, list):
        return [decode(v, arrays) for v in tree]
    if not isinstance(tree, dict) or len(tree) > 2:
        raise StateFormatError(f"unexpected state entry {str(tree)[:60]!r}")
    if "__array__" in tree:
        array = _array(arrays, tree["__array__"])
        return array[()] if tree.get("scalar") else array
    if "__tensor__" in tree:
        import torch as th

        return th.from_numpy(_array(arrays, tree["__tensor__"]))
    if "__generator__" in tree:
        return _generator(tree["__generator__"])
    if "__deque__" in tree:
        return deque((decode(v, arrays) for v in tree["__deque__"]), maxlen=tree.get("maxlen"))
    if "__tuple__" in tree:
        return tuple(decode(v, arrays) for v in tree["__tuple__"])
    if "__set__" in tree:
        items = (decode(v, arrays) for v in tree["__set__"])
        return frozenset(items) if tree.get("frozen") else set(items)
    if "__dict__" in tree:
        return {_hashable(decode(k, arrays)): decode(v, arrays) for k, v in tree["__dict__"]}
    raise StateFormatError(f"unexpected state entry {str(tree)[:60]!r}")


def _array(arrays: dict[str, np.ndarray], key: Any) -> np.ndarray:
    if not isinstance(key, str) or key not in arrays:
        raise StateFormatError(f"state refers to a missing array {key!r}")
    return np.array(arrays[key])  # a copy: the caller owns it


def _hashable(key: Any) -> Any:
    if isinstance(key, (list, dict, set, np.ndarray)):
        raise StateFormatError(f"unexpected state key {key!r}")
    return key


def _generator(state: Any) -> np.random.Generator:
    name = state.get("bit_generator") if isinstance(state, dict) else None
    if name not in BIT_GENERATORS:
        raise StateFormatError(f"unexpected bit generator {name!r}")
    bit_generator = getattr(np.random, name)()
    try:
        bit_generator.state = state
    except (TypeError, ValueError, KeyError) as error:
        raise StateFormatError(f"a malformed {name} state ({error})") from None
    return np.random.Generator(bit_generator)


#: The array of :func:`state_bytes`' archive that holds the JSON tree, as UTF-8 bytes.
TREE_ARRAY = "__tree__"


def state_bytes(value: Any) -> bytes:
    """``value`` as one in-memory ``.npz``: its arrays, and its JSON tree as the bytes of the array
    :data:`TREE_ARRAY` (for passing plain state to another process of ours)."""
    arrays: dict[str, np.ndarray] = {}
    tree = encode(value, arrays)
    arrays[TREE_ARRAY] = np.frombuffer(json.dumps(tree).encode(), dtype=np.uint8)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]  # names are strings
    return buffer.getvalue()


def state_from_bytes(data: bytes) -> Any:
    """The value :func:`state_bytes` wrote; never unpickles (``allow_pickle=False``).

    :raises StateFormatError: if ``data`` is malformed or holds anything but plain state.
    """
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
        tree = json.loads(arrays.pop(TREE_ARRAY).tobytes().decode())
        return decode(tree, arrays)
    except StateFormatError:
        raise
    except (ValueError, OSError, EOFError, KeyError, TypeError) as error:
        raise StateFormatError(f"plain state cannot be read ({error})") from None


def write_state(value: Any, json_path: Path, arrays_path: Path) -> None:
    """Write ``value`` as ``json_path`` (the tree) and ``arrays_path`` (its arrays, ``.npz``)."""
    arrays: dict[str, np.ndarray] = {}
    tree = encode(value, arrays)
    write_atomic(json_path, json.dumps(tree, sort_keys=True) + "\n")
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]  # names are strings
    with atomic_path(arrays_path) as temporary:
        temporary.write_bytes(buffer.getvalue())


def read_state(json_path: Path, arrays_path: Path) -> Any:
    """The value :func:`write_state` wrote; never unpickles (``allow_pickle=False``).

    :raises StateFormatError: if either file is malformed or holds anything but plain state.
    """
    try:
        tree = json.loads(json_path.read_text())
        with np.load(arrays_path, allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
    except (ValueError, OSError, EOFError) as error:
        if isinstance(error, FileNotFoundError):
            raise
        raise StateFormatError(f"{json_path.name}/{arrays_path.name} cannot be read ({error})") from None
    try:
        return decode(tree, arrays)
    except (TypeError, ValueError) as error:  # a crafted entry (a pair that is not one, a bad maxlen)
        if isinstance(error, StateFormatError):
            raise
        raise StateFormatError(f"{json_path.name} holds a malformed entry ({error})") from None


__all__ = [
    "BIT_GENERATORS",
    "TREE_ARRAY",
    "StateFormatError",
    "decode",
    "encode",
    "read_state",
    "state_bytes",
    "state_from_bytes",
    "write_state",
]
