"""The ``mercury-dem`` command line: a thin layer over the stage runners.

Each subcommand lives in its own module of :mod:`mercury_dem.commands` and
defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args, config) -> int``.
Modules there are discovered, so adding a command never edits this file.
Every subcommand takes ``--config FILE`` and ``--progress {auto,bar,lines,none}``
(:mod:`mercury_dem.progress`). Errors the package raises on purpose
(:class:`MercuryDemError`) are printed as one line, exit code 2; nothing else
is caught.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from mercury_dem import __version__, commands
from mercury_dem.config import load_config
from mercury_dem.exceptions import MercuryDemError
from mercury_dem.progress import MODES, set_default_mode


def _command_modules() -> list:
    mods = []
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{commands.__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            mods.append(mod)
    return sorted(mods, key=lambda m: m.NAME)


def build_parser() -> argparse.ArgumentParser:
    """The ``mercury-dem`` parser: global options and one subparser per discovered command module."""
    parser = argparse.ArgumentParser(
        prog="mercury-dem",
        description="Global planetary DEMs from orbital images: tile matching, hierarchical bundle "
        "adjustment and gridding on Dask (synthetic Mercury by default).",
    )
    parser.add_argument("--version", action="version", version=f"mercury-dem {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for mod in _command_modules():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP))
        p.add_argument("--config", metavar="FILE", help="YAML configuration (see 'mercury-dem config --template')")
        p.add_argument("--progress", choices=MODES, default=None,
                       help="progress of long stages: a live bar on a terminal, plain periodic lines in logs "
                            "(default auto: bar on a terminal, else lines; also MERCURY_DEM_PROGRESS)")
        mod.add_arguments(p)
        p.set_defaults(_module=mod)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``mercury-dem`` with ``argv`` (default ``sys.argv[1:]``); the exit code (2 on a project error)."""
    parser = build_parser()
    argv_given = argv
    argv = list(sys.argv[1:] if argv is None else argv)
    # Everything after a first '--' is a command for a subcommand that runs one (PASSTHROUGH, e.g. 'cluster').
    rest: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, rest = argv[:i], argv[i + 1:]
    args = parser.parse_args(argv)
    if rest and not getattr(args._module, "PASSTHROUGH", False):
        parser.error(f"'mercury-dem {args.command}' takes no command after '--' (got {' '.join(rest)!r})")
    args.passthrough = rest
    set_default_mode(args.progress)
    try:
        config = load_config(args.config)
        return int(args._module.run(args, config) or 0)
    except MercuryDemError as exc:
        print(f"mercury-dem {args.command}: error: {exc}", file=sys.stderr)
        return 2
    finally:
        if argv_given is None and getattr(args._module, "FREEZE_AT_EXIT", False):
            _freeze_for_exit()


def _freeze_for_exit() -> None:
    """Leave the objects alive now out of the interpreter's last garbage collections.

    For a command that ends its process (``main()`` called without ``argv``: the ``mercury-dem``
    program, ``python -m mercury_dem.cli``) and declares ``FREEZE_AT_EXIT`` (it closes what it
    opened itself): after numba has started, the collections at interpreter exit walk its typing and
    lowering registries, ~0.1-0.3 s of a cold ``mercury-dem grid`` (measured 2026-11-26,
    docs/benchmarks/dem.md); ``gc.freeze`` moves every live object to the permanent generation, which
    those collections skip. atexit handlers still run and reference counting still frees what it
    frees; the operating system reclaims the rest. Never done for ``main(argv)`` (tests, notebooks:
    a process that lives on).
    """
    import gc

    gc.freeze()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
