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


def first(bad: np.ndarray) -> int | None:
    """The index of the first True, or None."""
    return int(bad.argmax()) if bad.any() else None


def finite_rows(fields: dict[str, np.ndarray], label) -> None:
    """Every row of each field's values (n, ...) finite and squarable in double precision, else the first bad
    row of the first bad field named (`label(i)`: "body 'arm'"). One test covers all fields (NaN propagates
    through max); the culprit is looked for only when it fails."""
    flats = [values.reshape(len(values), -1) for values in fields.values()]
    flat = flats[0] if len(flats) == 1 else np.concatenate(flats, axis=1)
    if np.abs(flat).max(initial=0.0) <= LARGEST:
        return
    for (field, values), flat in zip(fields.items(), flats):
        i = first(~np.isfinite(flat).all(axis=1))
        if i is not None:
            raise SceneError(f"{label(i)} {field} contains NaN or Inf: {values[i].tolist()}")
        i = first(np.abs(flat).max(axis=1, initial=0.0) > LARGEST)
        if i is not None:
            raise SceneError(f"{label(i)} {field} is too large for double precision (|component| > "
                             f"{LARGEST:g}): {values[i].tolist()}")  # fmt: skip


def mass_properties(mass: np.ndarray, inertia: np.ndarray, dynamic: np.ndarray, label) -> None:
    """Masses (n,) kg and inertias (n, 3, 3) kg m^2 of bodies, the `dynamic` ones checked, naming the first bad
    body (`label(i)`): a positive finite mass and a finite symmetric positive definite inertia whose principal
    moments obey the triangle inequality (a + b >= c: no rigid body has others). The builder's check of every
    body, and `Simulator.set_masses`'."""
    i = first(dynamic & ~(np.isfinite(mass) & (mass > 0.0)))
    if i is not None:
        raise SceneError(f"{label(i)}: mass must be positive and finite, got {mass[i]}")
    flat = inertia.reshape(len(inertia), 9)  # reductions over one axis: cheaper than over (1, 2)
    i = first(dynamic & ~np.isfinite(flat).all(axis=1))
    if i is not None:
        raise SceneError(f"{label(i)}: inertia contains NaN or Inf")
    scale = np.maximum(np.abs(flat).max(axis=1, initial=0.0), 1e-300)
    asymmetry = np.abs(flat - inertia.transpose(0, 2, 1).reshape(len(inertia), 9)).max(axis=1, initial=0.0)
    i = first(dynamic & (asymmetry > 1e-9 * scale))
    if i is not None:
        raise SceneError(f"{label(i)}: inertia tensor is not symmetric")
    moments = np.linalg.eigvalsh(inertia if dynamic.all() else np.where(dynamic[:, None, None], inertia, np.eye(3)))
    smallest, middle, largest = moments.T
    i = first(smallest <= 0.0)
    if i is not None:
        raise SceneError(f"{label(i)}: inertia tensor is not positive definite (moments {moments[i].tolist()})")
    i = first(smallest + middle < largest * (1.0 - 1e-9))
    if i is not None:
        raise SceneError(f"{label(i)}: principal moments {moments[i].tolist()} break the triangle inequality")


def available_memory() -> int:
    """Bytes this process may still allocate: the memory the system has available (Linux's MemAvailable, else its
    free physical pages), less what an address-space limit (`ulimit -v`, RLIMIT_AS) leaves of it."""
    import os

    free = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    free = int(line.split()[1]) * 1024
    except OSError:
        pass
    if free is None:
        free = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
        if limit != resource.RLIM_INFINITY:
            with open("/proc/self/status") as f:
                used = next((int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:")), 0)
            free = min(free, max(limit - used, 0))
    except (ImportError, OSError, ValueError):
        pass
    return int(free)


def affordable(count: int, each: float, what: str, unit: str) -> None:
    """Refuse (SceneError naming `what`, the count of `unit`s and the estimate) `count` items of about `each`
    bytes when they would not fit in the memory this process may still allocate (`available_memory`): checked
    before the allocation, so that a huge count is one line and not numpy's MemoryError."""
    need, free = count * each, available_memory()
    if need > free:
        raise SceneError(f"{what}: {count:,} {unit}s would take about {_size(need)} of memory ({_size(each)} a "
                         f"{unit}), more than this machine has free ({_size(free)})")  # fmt: skip


def _size(n: float) -> str:
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n:.3g} B"
