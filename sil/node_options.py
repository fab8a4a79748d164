"""Options the node commands share (`sil ecu`, `sil plant`), and the PIL link option that
`sil run` passes on to `sil ecu`: one definition each."""

from __future__ import annotations

import argparse
from pathlib import Path

from ecu.port.build import PIL_LINKS


def add_launcher_options(parser: argparse.ArgumentParser) -> None:
    """--run-tag and --stats-file, as a launcher (sil run) gives them to a node."""
    parser.add_argument(
        "--run-tag",
        type=int,
        default=0,
        metavar="TAG",
        help="the run's tag on a shared bus (protocol.run_tag; sil run claims it): 0 sends "
        "the DBC IDs as they are; frames of other tags are dropped and counted",
    )
    parser.add_argument(
        "--stats-file",
        type=Path,
        metavar="PATH",
        help="write the run summary (frames, timeouts; in real time the periods' jitter and "
        "overruns) as JSON to this file at the end (for launchers)",
    )


def add_pil_link(parser: argparse.ArgumentParser, applies: str) -> None:
    """--pil-link; ``applies``: the option it goes with (``--impl pil``...)."""
    parser.add_argument(
        "--pil-link",
        choices=tuple(PIL_LINKS),
        default="eth",
        help=f"with {applies}: the image's CAN link, its Ethernet controller (eth, one frame per "
        "Ethernet frame) or slcan on its UART (as a USB-CAN adapter; slower)",
    )
