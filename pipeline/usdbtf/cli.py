"""``usdbtf <stage>``: thin command-line mains over the library.

Every command reads real files, writes its output atomically, and on bad input
prints one line naming the file or sample and exits with status 2.  The commands
themselves live in :mod:`usdbtf.commands`, one module each.
"""
from __future__ import annotations

import argparse
import sys

from . import __version__
from .commands import command_modules
from .errors import BTFError

EXIT_BAD_INPUT = 2


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="usdbtf", description="Measured BTF materials to USD assets.")
    p.add_argument("--version", action="version", version=f"usdbtf {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="<stage>")
    for module in command_modules():
        module.add_parser(sub)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BTFError as exc:
        print(f"usdbtf {args.command}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"usdbtf {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
