"""Options the node commands share (`sil ecu`, `sil plant`), the PIL link option that `sil run`
passes on to `sil ecu`, and the XCP identifiers of `sil ecu` and `sil a2l`: one definition
each."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from ecu.port.build import PIL_LINKS

if TYPE_CHECKING:
    from protocol.codec import Codec


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
        "--foreign-frames",
        choices=("ids", "sequence"),
        help="in a run (sil run gives it): drop and count another sender's frames: 'ids' those "
        "of the IDs this node sends, 'sequence' also those that break the run's lockstep "
        "sequence (protocol.run_sequence)",
    )
    parser.add_argument(
        "--stats-file",
        type=Path,
        metavar="PATH",
        help="write the run summary (frames, timeouts; in real time the periods' jitter and "
        "overruns) as JSON to this file at the end (for launchers)",
    )


def run_sequence(  # noqa: ANN201 (RunSequence | None: protocol imported when needed)
    args: argparse.Namespace, codec: Codec | None, role: str, rate_hz: float
):
    """The node's :class:`~protocol.run_sequence.RunSequence` as ``--foreign-frames`` asks
    (None without it); ``role``: the DBC sender the node is (Plant, ECU); ``codec``: the
    node's, or None for one of its own."""
    from protocol.codec import Codec
    from protocol.run_sequence import RunSequence, sent_by

    if args.foreign_frames is None or getattr(args, "impl", None) == "pil":
        return None  # (the image in the loop paces its own turns: its bridge takes them all)
    codec = codec or Codec()
    strict = args.foreign_frames == "sequence"
    return RunSequence(codec, rate_hz, sent_by(codec, role), strict=strict)


def add_pil_link(parser: argparse.ArgumentParser, applies: str) -> None:
    """--pil-link; ``applies``: the option it goes with (``--impl pil``...)."""
    parser.add_argument(
        "--pil-link",
        choices=tuple(PIL_LINKS),
        default="eth",
        help=f"with {applies}: the image's CAN link, its Ethernet controller (eth, one frame per "
        "Ethernet frame) or slcan on its UART (as a USB-CAN adapter; slower)",
    )


def xcp_ids(text: str) -> tuple[int, int]:
    """MASTER,ECU: two standard CAN IDs (hex with 0x, or decimal), distinct, of no other
    message of the contract."""
    from protocol.dbc import is_xcp, load_database

    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        ids = tuple(int(part.strip(), 0) for part in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected two CAN IDs MASTER,ECU (e.g. 0x700,0x701)"
        ) from None
    if not all(0 <= i <= 0x7FF for i in ids) or ids[0] == ids[1]:
        raise argparse.ArgumentTypeError(f"{text!r}: two different standard IDs, 0..0x7FF")
    taken = {m.frame_id: m.name for m in load_database().messages if not is_xcp(m)}
    for i in ids:
        if i in taken:
            raise argparse.ArgumentTypeError(f"{text!r}: 0x{i:03X} is {taken[i]}'s ID")
    return ids[0], ids[1]
