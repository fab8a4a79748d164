"""One module per `sil` subcommand (as cantools does).

Each module defines ``NAME`` (the subcommand), ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int`` (the exit code). Modules are discovered by name, so adding a subcommand is
adding a file.
"""
