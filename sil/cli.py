"""The `sil` command line: discovers the subcommands in `sil.commands`."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from types import ModuleType

from sil import commands


def _command_modules() -> list[ModuleType]:
    names = sorted(m.name for m in pkgutil.iter_modules(commands.__path__))
    return [importlib.import_module(f"sil.commands.{name}") for name in names]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sil",
        description="Turbojet ECU emulator and software-in-the-loop harness over CAN.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in sorted(_command_modules(), key=lambda m: m.NAME):
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("sil: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
