"""A parameter set as C: the integers ``compile_params`` computes for a preset, written as a
``const ecu_params_t`` (designated initializers, so it lives in flash and names its fields) for
firmware that does not load its calibration at run time.

    python -m ecu.port.export [--preset NAME] [--param NAME=VALUE ...] [--name IDENT] > params.c
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields

from ecu.firmware_params import FirmwareParams, compile_params
from ecu.params import EcuParams, ParamError, preset
from ecu.port.core import param_words


def to_c(p: FirmwareParams, name: str, source: str) -> str:
    """C source defining ``const ecu_params_t <name>`` with the values of ``p``."""
    param_words(p)  # refuses a value that is not an int32 word, naming it
    lines = [
        f"/* {name}: ECU parameters from {source}, by python -m ecu.port.export */",
        '#include "ecu_core.h"',
        "",
        f"const ecu_params_t {name} = {{",
    ]
    for field in FirmwareParams.FIELDS:
        value = getattr(p, field)
        if isinstance(value, tuple):
            lines.append(f"    .{field} = {{{', '.join(f'{v}' for v in value)}}},")
        else:
            lines.append(f"    .{field} = {value},")
    lines.append("};")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ecu.port.export", description=__doc__)
    parser.add_argument("--preset", default="default", help="parameter preset (ecu.params)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--name", default="ecu_params", help="C identifier of the constant")
    args = parser.parse_args(argv)
    known = {f.name for f in fields(EcuParams)}
    overrides: dict[str, object] = {}
    for text in args.param:
        key, sep, value = (part.strip() for part in text.partition("="))
        try:
            if not sep or key not in known:
                raise ValueError
            overrides[key] = float(value)
        except ValueError:
            print(
                f"ecu.port.export: --param {text!r}: expected NAME=NUMBER with NAME an "
                "EcuParams field",
                file=sys.stderr,
            )
            return 2
    try:
        p = compile_params(preset(args.preset, **overrides))
    except (ParamError, ValueError, TypeError) as exc:
        print(f"ecu.port.export: {exc}", file=sys.stderr)
        return 2
    sys.stdout.write(to_c(p, args.name, f"preset {args.preset!r} {' '.join(args.param)}".strip()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
