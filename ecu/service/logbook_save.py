"""The engine's logbook in flash: loaded at power-up from the stored set, saved with it.

The logbook (ecu.logbook) goes into the same slot as the parameter set (ecu.service.storage:
sequence and CRC, the other slot untouched until the new one is whole), so a save of either
writes both: a parameter store (the service port's PARAM_SAVE, XCP's SET_REQUEST STORE_CAL) takes
the logbook as it is, and :class:`LogbookSaver` saves the set by itself when the ECU has come
to rest (back in OFF after a start or a run, or latched in FAULT), one flash operation per tick
as the other saves, and at once on an orderly stop (:meth:`LogbookSaver.at_stop`), whatever the
engine is doing. A stored set without a logbook (saved before it existed) leaves it at zero.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ecu import logbook as L
from ecu import modes as M
from ecu.service.param_table import stored_logbook
from ecu.service.storage import FlashImage, Slot, SlotWriter


def load(ecu: Any, payload: bytes | None) -> list[str]:
    """Power-up: the stored set's logbook into the firmware's state (Python or C); returns the
    problems (none when the set has no logbook: it starts at zero)."""
    if payload is None:
        return []
    stored = stored_logbook(payload)
    return [] if stored is None else L.load_words(ecu.s, stored)


class LogbookSaver:
    """Saves the stored set (``image()``: parameters and logbook) into ``flash`` once the ECU
    ``ecu`` is at rest again; ``busy()`` says another save is under way (it waits for it),
    ``on_begin()`` is told when a save begins, ``on_end(slot)`` when it is whole (None: it
    failed). Call :meth:`after_tick` after each tick."""

    def __init__(
        self,
        ecu: Any,
        flash: FlashImage,
        image: Callable[[], bytes],
        busy: Callable[[], bool] = lambda: False,
        on_end: Callable[[Slot | None], None] = lambda slot: None,
        on_begin: Callable[[], None] = lambda: None,
    ) -> None:
        self.ecu = ecu
        self.flash = flash
        self.image = image
        self.busy = busy
        self.on_begin = on_begin
        self.on_end = on_end
        self.mode = M.OFF
        self.pending = False
        self.writer: SlotWriter | None = None
        self.saves = 0
        self.failures = 0

    def after_tick(self) -> None:
        mode = self.ecu.out.mode
        if mode != self.mode and (mode == M.OFF or mode == M.FAULT):
            self.pending = True  # a start or a run ended: its counts go to flash
        self.mode = mode
        try:
            if self.writer is None:
                if self.pending and not self.busy():
                    self.pending = False
                    self.writer = self.flash.writer(self.image())
                    self.on_begin()
                return
            if self.writer.step():
                slot = self.writer.slot
                self.writer = None
                self.saves += 1
                self.on_end(slot)
        except (OSError, ValueError):
            self.writer = None
            self.failures += 1
            self.on_end(None)

    def at_stop(self) -> Slot | None:
        """An orderly stop (SIGTERM, Ctrl-C): what the firmware has counted and flash does not
        hold yet (a run or a cool-down under way, a save at rest not yet begun or not yet
        whole) is saved now, whole; the slot saved, or None when flash held it all. A save of
        another under way is taken over: this one carries the same set. Raises OSError when the
        image cannot be written."""
        counted = L.stored_dict(self.ecu.s)
        newest = self.flash.newest()
        held = None if newest is None else stored_logbook(newest.payload)
        if self.writer is None and counted == (held or dict.fromkeys(counted, 0)):
            return None
        self.writer = None
        slot = self.flash.save(self.image())
        self.saves += 1
        self.on_end(slot)
        return slot


def boot_saver(ecu: Any, boot: Any) -> LogbookSaver:
    """The saver of a node whose saves share ``boot`` (ecu.service.port.Boot) with the service
    port and the Python XCP slave: one save at a time (``boot.saving``), the slot saved
    recorded in it."""

    def begin() -> None:
        boot.saving = saver

    def end(slot: Slot | None) -> None:
        boot.saving = None
        if slot is not None:
            boot.state, boot.slot, boot.sequence = "loaded", slot.index, slot.sequence

    saver = LogbookSaver(
        ecu,
        boot.flash,
        lambda: boot.table.stored_image(L.stored_dict(ecu.s)),
        busy=lambda: boot.saving is not None,
        on_end=end,
        on_begin=begin,
    )
    return saver
