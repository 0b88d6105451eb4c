"""Checks of user input shared by the builder, the model and the simulator.

Every check raises SceneError (a ValueError) whose message names the argument at fault (`what`), so a wrong
type (a string, a boolean, None, a ragged list) never reaches numpy or Warp as an anonymous error, and is
never silently taken as a number (`mass=True` is not 1 kg, `"1e-6"` is not a tolerance).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

# Components above this in magnitude cannot be squared in double precision (1e154**2 overflows): a state
# holding them could not be checked, let alone simulated.
LARGEST = 1e150


class SceneError(ValueError):
    """Invalid scene input: the message names the body, joint or value at fault."""


def numbers(value: Any, what: str) -> np.ndarray:
    """`value` as a float64 array. Refuses None, strings, booleans, ragged lists and anything not numeric."""
    if value is None:
        raise SceneError(f"{what} must be a number, got None")
    if isinstance(value, (str, bytes)):
        raise SceneError(f"{what} must be numeric, got the string {value!r}")
    try:
        raw = np.asarray(value)
    except (ValueError, TypeError):  # a ragged list: numpy cannot make it an array
        raise SceneError(f"{what} must be a regular array of numbers, not a ragged list: got {value!r}") from None
    if raw.dtype.kind == "b":
        raise SceneError(f"{what} must be numeric, got the boolean {value!r}")
    if raw.dtype.kind not in "iuf":
        raise SceneError(f"{what} must be numeric, got {value!r}")
    return raw.astype(np.float64)


def real(value: Any, what: str) -> float:
    """One real number (possibly NaN or Inf: the caller decides)."""
    arr = numbers(value, what)
    if arr.ndim != 0:
        raise SceneError(f"{what} must be a single number, got {value!r}")
    return float(arr)


def positive(value: Any, what: str, unit: str = "") -> float:
    """A positive finite number."""
    x = real(value, what)
    if not (math.isfinite(x) and x > 0.0):
        raise SceneError(f"{what} must be positive and finite{unit}, got {x!r}")
    return x


def integer(value: Any, what: str, minimum: int) -> int:
    """An integer >= minimum (a float such as 10.0 or a boolean is refused, not rounded)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise SceneError(f"{what} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def vector(value: Any, what: str, n: int = 3) -> np.ndarray:
    """n finite components of a size that double precision can square; a single number fills all n."""
    arr = numbers(value, what)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise SceneError(f"{what} must have {n} components, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{what} contains NaN or Inf: {arr.tolist()}")
    if np.abs(arr).max() > LARGEST:
        raise SceneError(f"{what} is too large for double precision (|component| > {LARGEST:g}): {arr.tolist()}")
    return arr


def name(value: Any, what: str) -> str:
    """A non-empty string (the name messages use to point at a body or joint)."""
    if not isinstance(value, str) or not value:
        raise SceneError(f"{what} must be a non-empty string, got {value!r}")
    return value


def device(name: Any):
    """The Warp device `name` (`verbosity.device`: the first call initialises Warp quietly), or a SceneError
    naming it and the devices this machine has (Warp raises RuntimeError for "cuda" without a GPU and
    ValueError for an unknown name)."""
    import warp as wp

    from .verbosity import device as warp_device

    if str(name).startswith("cuda"):  # ask Warp how many GPUs before it tries one (and prints CUDA errors)
        warp_device("cpu")
        if wp.get_cuda_device_count() == 0:
            raise SceneError(f"device {name!r} is not available (Warp finds no CUDA GPU or driver); this machine "
                             "has: cpu")  # fmt: skip
    try:
        return warp_device(name)
    except (RuntimeError, ValueError, TypeError) as err:
        here = ", ".join(d.alias for d in wp.get_devices())
        raise SceneError(f"device {name!r} is not available ({err}); this machine has: {here}") from None
