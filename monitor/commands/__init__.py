"""One module per ``dexmon`` subcommand.

Each module defines ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int`` (0 clean, 1 findings, 2 error). :mod:`monitor.cli` imports a module
only when its subcommand is used, so a slow import (pyvista, pymodbus) costs nothing
elsewhere.
"""
