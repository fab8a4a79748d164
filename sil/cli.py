"""The `sil` command line: discovers the subcommands in `sil.commands`.

Each subcommand is one module, named as the command with ``-`` for ``_``. A node process (`sil
ecu`, `sil plant`) must start fast, so when the command is known only its module is imported
(scipy, matplotlib and numba stay out of the ECU process); `sil --help` or an unknown command
imports them all to list them. python-can comes without its MF4 classes, which no command uses
(:mod:`protocol.python_can`).
"""

from __future__ import annotations

import argparse
import gc
import importlib
import os
import pkgutil
import sys
from types import ModuleType

from protocol.python_can import import_without_mf4

import_without_mf4()  # before any command's module imports python-can

from sil import commands  # noqa: E402
from sil.validation import InputError  # noqa: E402


def _command_modules(argv: list[str]) -> list[ModuleType]:
    names = sorted(m.name for m in pkgutil.iter_modules(commands.__path__))
    wanted = next((a.replace("-", "_") for a in argv if not a.startswith("-")), None)
    if wanted in names:
        names = [wanted]
    return [importlib.import_module(f"sil.commands.{name}") for name in names]


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser; with `argv`, only for the command that `argv` names (when it names one)."""
    parser = argparse.ArgumentParser(
        prog="sil",
        description="Turbojet ECU emulator and software-in-the-loop harness over CAN.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in sorted(_command_modules(argv or []), key=lambda m: m.NAME):
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(argv).parse_args(argv)
    args.command_line = ("sil", *argv)  # as typed (a run records it in its folder)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("sil: interrupted", file=sys.stderr)
        return 130
    except InputError as exc:  # a user error no command caught: one line, exit 2
        prefix = f"sil {args.command}"
        print(exc if str(exc).startswith(prefix) else f"{prefix}: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader went away (`sil scenarios | head -1`): not an error
        _quiet_stdout()
        return 0


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's final flush into the closed pipe
    raises nothing."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


if __name__ == "__main__":  # how `sil run` starts its node processes
    code = main()
    # The process ends: what it holds is frozen, so that the interpreter's last collection
    # skips it (a plant process, with numba loaded, would spend 0.6 s of the run on it).
    gc.freeze()
    sys.exit(code)
