"""One module per ``mercury-dem`` subcommand (discovered by :mod:`mercury_dem.cli`).

A module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args, config) -> int`` and does nothing but parse, call the library and
print.
"""
