"""Warp's own messages: quiet unless asked.

Warp prints a start-up banner and a `Module ... load on device ... took ... ms` line per kernel module at
info level (`wp.config.log_level`, default `wp.LOG_INFO`; Warp 1.19 no longer reads `wp.config.quiet`),
and its native library writes "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver" to file
descriptor 2 from `wp.init()` on a machine without a GPU driver, whatever the log level. None of it helps
someone simulating on the CPU, so `import warpimpulse` lowers the level to warnings (`quiet_by_default`),
`Simulator(verbose=True)` / `warpimpulse simulate --verbose` raise it again (`verbose`), and `device`
initialises Warp with that one warning filtered out unless a CUDA device is asked for.
"""

from __future__ import annotations

import os
import sys
import tempfile

import warp as wp

_DRIVER_WARNING = b"Warp CUDA warning: Could not find or load the NVIDIA CUDA driver"
_initialised = False


def quiet_by_default() -> None:
    """Warp's info messages off, unless the level was already set to something other than Warp's default."""
    if wp.config.log_level == wp.LOG_INFO:
        wp.config.log_level = wp.LOG_WARNING


def verbose() -> None:
    """Warp's info messages on: the banner (if Warp is not initialised yet) and the module loads."""
    wp.config.log_level = min(wp.config.log_level, wp.LOG_INFO)


def device(spec: str | wp.Device | None = None) -> wp.Device:
    """`wp.get_device(spec)`; the first call initialises Warp, without the missing-CUDA-driver warning unless
    `spec` names a CUDA device (where the warning explains the error that follows)."""
    global _initialised
    if not _initialised:
        wants_cuda = str(spec).startswith("cuda") or getattr(spec, "is_cuda", False)
        if wants_cuda:
            wp.init()
        else:
            _init_without_driver_warning()
        _initialised = True
    return wp.get_device(spec)


def _init_without_driver_warning() -> None:
    """wp.init() with file descriptor 2 caught; everything it wrote there but the driver warning is passed on."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as caught:
            os.dup2(caught.fileno(), 2)
            try:
                wp.init()
            finally:
                sys.stderr.flush()
                os.dup2(saved, 2)
            caught.seek(0)
            lines = caught.read().splitlines(keepends=True)
    finally:
        os.close(saved)
    rest = b"".join(line for line in lines if not line.startswith(_DRIVER_WARNING))
    if rest:
        os.write(2, rest)
