"""Every kernel module compiles for a GPU (PTX for sm_90 through the NVRTC in Warp's wheel), on every machine:
a kernel that only a CUDA compiler rejects fails here, not on the first machine with a GPU. Nothing runs on a
GPU; no GPU is needed."""

from __future__ import annotations

import importlib
import pkgutil

import pytest
import warp as wp
import warpimpulse.kernels

from warpimpulse.verbosity import device

ARCH = 90


def cuda_compiler() -> bool:
    """Whether this Warp build carries CUDA (and so NVRTC); builds without it (macOS) skip these tests."""
    device("cpu")  # initialise Warp quietly
    from warp._src.context import runtime

    return bool(runtime.is_cuda_enabled)


pytestmark = [
    pytest.mark.skipif(not cuda_compiler(), reason="this Warp build has no CUDA compiler"),
    pytest.mark.schedule_free,  # ~5 minutes of compilation on 2 cores: once a `make test`, not once a schedule
]


def kernel_modules() -> list:
    """Every module of warpimpulse.kernels with kernels of its own (not the funcs-only ones)."""
    modules = []
    for info in pkgutil.iter_modules(warpimpulse.kernels.__path__, "warpimpulse.kernels."):
        module = importlib.import_module(info.name)
        if any(isinstance(v, wp.Kernel) for v in vars(module).values()):
            modules.append(module)
    return modules


def factories() -> list:
    """The kernel factories of warpimpulse.kernels (cached functions of a set of constraint kinds that build a
    module of kernels, such as `constraints.specialized`)."""
    found = []
    for info in pkgutil.iter_modules(warpimpulse.kernels.__path__, "warpimpulse.kernels."):
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if callable(value) and hasattr(value, "cache_info") and getattr(value, "__module__", "") == info.name:
                found.append(pytest.param(value, id=f"{info.name.rpartition('.')[2]}.{name}"))
    return found


def compile_for_cuda(module, tmp_path) -> None:
    paths = wp.compile_aot_module(module, arch=ARCH, use_ptx=True, module_dir=tmp_path)
    assert paths and all(p.suffix == ".ptx" and p.stat().st_size > 0 for p in paths)


@pytest.mark.parametrize("module", kernel_modules(), ids=lambda m: m.__name__.rpartition(".")[2])
def test_kernel_module_compiles_for_cuda(module, tmp_path):
    compile_for_cuda(module, tmp_path)


def specialized_modules(factory, kinds) -> set:
    built = factory(frozenset(kinds))
    return {v.module for v in vars(built).values() if isinstance(v, wp.Kernel)}


@pytest.mark.parametrize("factory", factories())
def test_specialised_modules_compile_for_cuda(factory, tmp_path):
    """The module of all six constraint kinds: every branch of the dispatch at once."""
    from warpimpulse.kernels.constraints import ALL_KINDS

    for module in specialized_modules(factory, ALL_KINDS):
        compile_for_cuda(module, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("factory", factories())
def test_each_kind_alone_compiles_for_cuda(factory, tmp_path):
    """Each constraint kind alone: every other branch folded away (`wp.static`)."""
    from warpimpulse.kernels.constraints import ALL_KINDS

    for kind in sorted(ALL_KINDS):
        for module in specialized_modules(factory, {kind}):
            compile_for_cuda(module, tmp_path)


def test_the_fused_step_with_force_elements_compiles_for_cuda(tmp_path):
    """`step.fused(kinds, forced=True)`: the coupled RK4 prediction and the drives' integrals in the fused loop;
    with `kicked=True` as well, the half kicks about each base step (`split_forces`) in the same module: the
    simulator never takes both, but one compile covers both paths' code (a module of its own took 97 s)."""
    from warpimpulse.kernels import step
    from warpimpulse.kernels.constraints import ALL_KINDS

    compile_for_cuda(step.fused(ALL_KINDS, forced=True, kicked=True).cholesky_steps.module, tmp_path)


def test_the_fused_step_with_rows_compiles_for_cuda(tmp_path):
    """`step.fused(kinds, forced=True, rows=True)`: limits, stiff motors and distance rows in the fused loop, with
    force elements (the held car has both)."""
    from warpimpulse.kernels import step
    from warpimpulse.kernels.constraints import ALL_KINDS

    compile_for_cuda(step.fused(ALL_KINDS, forced=True, rows=True).cholesky_steps.module, tmp_path)
