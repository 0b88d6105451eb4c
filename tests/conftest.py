"""Test session set-up: Warp quiet. Shared checks live in numpy_checks.py (independent numpy references of the
engine's state), reference.py (reduced-coordinate and free-body references), rigs.py (random joint rigs) and
cli_helpers.py (running the command line); tests import those, never each other."""

import warp as wp

wp.config.quiet = True
# Warp 1.19 no longer reads `config.quiet`; its start-up and module-load messages are info-level logs.
wp.config.log_level = getattr(wp, "LOG_WARNING", 30)
