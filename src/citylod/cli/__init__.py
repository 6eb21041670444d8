"""citylod: city-scale 3D geodata through level-of-detail hierarchies with a guaranteed error.

The ``citylod`` command.

One module per subcommand (``add_parser`` and ``run``), registered in :data:`COMMANDS`, the one table of
commands. Each subcommand imports what it needs when it runs, so ``citylod --help`` is fast and a machine
without a display can run every command but ``view``. A :class:`~citylod.core.errors.CitylodError` becomes
one line on stderr and exit code 2; a warning becomes one line ``citylod: warning: ...`` (not Python's two,
whose second repeats the source line that raised it).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from collections.abc import Sequence
from typing import Any, TextIO

from citylod._version import __version__
from citylod.core.errors import CitylodError

#: Subcommand name -> module of this package that defines ``add_parser(sub)`` and ``run(args, progress)``.
COMMANDS: dict[str, str] = {
    "sample": "sample",
    "build": "build",
    "info": "info",
    "render": "render",
    "bench": "bench",
    "bench-suite": "bench",
    "bench-slf": "bench",
    "link": "link",
    "view": "view",
    "demo": "demo",
    "build-kernels": "kernels",
    "flood": "flood",
    "pack": "pack",
}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="citylod", description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars")
    p.add_argument("--version", action="version", version=f"citylod {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in dict.fromkeys(COMMANDS.values()):
        importlib.import_module(f"citylod.cli.{module}").add_parser(sub)
    return p


def show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                 file: TextIO | None = None, line: str | None = None) -> None:
    """:func:`warnings.showwarning` for the command line: one line, ``citylod: warning: MESSAGE``; the
    category is named unless it is a plain UserWarning (citylod's own)."""
    text = " ".join(str(message).split())
    kind = "" if category is UserWarning else f"{category.__name__}: "
    print(f"citylod: warning: {kind}{text}", file=sys.stderr if file is None else file)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    progress = not args.quiet
    with warnings.catch_warnings():  # the hook only while a command runs: callers of main() keep theirs
        warnings.showwarning = show_warning
        return _run(args, progress)


def _run(args: Any, progress: bool) -> int:
    try:
        return int(importlib.import_module(f"citylod.cli.{COMMANDS[args.command]}").run(args, progress))
    except CitylodError as exc:
        print(f"citylod: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("citylod: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (``citylod info X | head``): stop quietly, as Unix tools do. Point stdout at
        # /dev/null so the interpreter's final flush does not raise again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141  # 128 + SIGPIPE
