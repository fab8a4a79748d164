"""``python -m ecu.build_tick``: build the firmware tick's compiled modules (ecu.compiled_tick)."""

from __future__ import annotations

import argparse
import sys

from ecu import compiled_tick


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m ecu.build_tick",
        description="build the firmware tick's compiled modules (mypyc) from their source",
    )
    parser.add_argument("action", choices=["build", "status"], help="build: compile; status: "
                        "say whether a current build is there")  # fmt: skip
    parser.add_argument("--if-stale", action="store_true", help="build only when the sources "
                        "changed since the last build")  # fmt: skip
    args = parser.parse_args(argv)
    if args.action == "status":
        ok = compiled_tick.current()
        print(f"{compiled_tick.BUILD_DIR}: {'current' if ok else 'stale or missing'}")
        return 0 if ok else 1
    if args.if_stale and compiled_tick.current():
        return 0
    try:
        compiled_tick.build()
    except compiled_tick.BuildError as exc:
        print(f"ecu.build_tick: {exc}\nthe tick runs interpreted", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
