"""Launches bound by name: a kernel's parameters are named after the fields they read and write.

A parameter `name` takes, in order: an explicit keyword value; for `name_in` / `name_out`, the field `name` of
the `data_in` / `data_out` object (a State read or written, so one kernel can read one state and write
another); else the field `name` (suffix stripped) of the first source that has it (Model, Frames, solver
scratch). So a kernel's signature is the only list of its arguments, and renaming a field or a parameter
without the other fails when the launch is recorded, naming both.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Callable, Sequence

import warp as wp


class Nothing:
    """Stands for a launch over zero elements (Warp records none): a scene of free bodies has no constraints."""

    def launch(self) -> None:
        pass


class Launches:
    """Recorded launches that always run in this order (a prediction of several stages), as one item of work."""

    def __init__(self, launches: Sequence[wp.Launch | Nothing]) -> None:
        self.launches = list(launches)

    def launch(self) -> None:
        for item in self.launches:
            item.launch()


class Packed:
    """A recorded CPU launch whose arguments are packed once: `launch()` is one call of the kernel's compiled entry
    point with them (~0.3 us for the fused step's 90 arguments), where a captured graph's replay packs them again
    each time (~1.7 us; docs/architecture.md, "Measured facts"). Its arrays are bound by address, as a graph's are,
    so what the host writes into them between calls is read; Warp's own CPU launch (`invoke`) packs the same
    structure of the same ctypes values. Never captured: a capture on another thread does not take it in."""

    def __init__(self, launch: wp.Launch) -> None:
        if not launch.device.is_cpu or launch.adjoint or launch.block_dim != 1:
            raise ValueError(f"kernel {launch.kernel.key}: only a forward CPU launch of one thread a task is packed")
        values = launch.params[1:]  # after the launch bounds
        fields = [(arg.label, type(value)) for arg, value in zip(launch.kernel.adj.args, values, strict=True)]
        self._args = type("Args", (ctypes.Structure,), {"_fields_": fields})(*values)
        self._launch = launch  # keeps the bounds and the arrays the arguments point into
        # `launch()`: the entry point bound to its two pointers, called without a Python frame
        self.launch = functools.partial(launch.hooks.forward, ctypes.byref(launch.params[0]), ctypes.byref(self._args))

    def set(self, name: str, value: float | int) -> None:
        """Change the scalar argument `name` in place (the next `launch()` reads it): one packed launch then
        serves every value, such as every step size of an accuracy-controlled run, where recording one a value
        costs ~1 ms."""
        setattr(self._args, name, value)


Work = wp.Launch | Nothing | Launches | Callable[[], object]


def _strip(name: str) -> str:
    for suffix in ("_in", "_out"):
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return name


def arguments(
    kernel: wp.Kernel, sources: Sequence[object], data_in: object = None, data_out: object = None, **values
) -> list:
    """The kernel's arguments in order, each found by its parameter's name (see the module docstring)."""
    out = []
    for arg in kernel.adj.args:
        name = arg.label
        if name in values:
            out.append(values[name])
            continue
        field = _strip(name)
        first = data_in if name.endswith("_in") else data_out if name.endswith("_out") else None
        for source in (first, *sources):
            if source is not None and hasattr(source, field):
                out.append(getattr(source, field))
                break
        else:
            raise KeyError(f"kernel {kernel.key}: no value for parameter {name!r} (field {field!r})")
    return out


def record(
    kernel: wp.Kernel,
    dim: int | tuple[int, ...],
    device,
    sources: Sequence[object] = (),
    data_in: object = None,
    data_out: object = None,
    **values,
) -> wp.Launch | Nothing:
    """A recorded launch of `kernel` over `dim`, its arguments bound by name; a `Nothing` over zero elements."""
    if dim == 0:
        return Nothing()
    inputs = arguments(kernel, sources, data_in, data_out, **values)
    return wp.launch(kernel, dim=dim, inputs=inputs, device=device, record_cmd=True)


def run(*work: Work) -> None:
    """Each item of work in turn: a launch is launched, anything else (an array copy, a nested loop) called."""
    for item in work:
        item.launch() if isinstance(item, (wp.Launch, Nothing, Launches)) else item()


def capture(device, *work: Work) -> wp.Graph:
    """Launches (or array copies) that always run together, replayed as one captured graph: on a CPU about
    0.3 us a launch against 3-5 us for a recorded one (docs/architecture.md, "Measured facts")."""
    wp.capture_begin(device=device)
    try:
        run(*work)
    finally:
        graph = wp.capture_end(device=device)
    return graph
