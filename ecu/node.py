"""The ECU as a CAN node: a thin sans-IO layer between the protocol codec and the firmware tick.

Frames are decoded with :mod:`protocol.codec` (raw integers, which are already the firmware's
units: rpm, 0.1 K, mV, mA, 0.01 %) and checked with its E2E checkers; the per-frame-kind status
of what arrived since the last tick goes to the firmware with the values (see
:class:`ecu.firmware.EcuInputs`). Outputs go back as EcuStatus and EcuTelemetry when due,
EcuStarter while the ECU is ARMED or in SHUTDOWN (the start/stop sequencer drives the starter
and igniter) or a bench test function drives them in OFF (and the tick after, which says they
ended), then EcuActuator last, following :mod:`protocol.lockstep`:

- lockstep: one tick per PlantSensors frame, answered with ActuatorTick = SensorTick; when a
  Demand is due at that tick (and the command node sends ticked demands) the tick waits for it,
  or for the driver's wall-clock guard (``on_timeout``), after which it runs without it;
- real time: one tick per period of the node's own clock (``on_period``), with whatever frames
  arrived in between; ActuatorTick counts the node's own ticks.

An XCP slave (:mod:`ecu.xcp.slave`, :meth:`EcuNode.attach_xcp`) takes the master's command
frames as they come and is served at the tick boundary, before the firmware's tick (its
answers go out first); its DAQ lists are sampled after the tick and their DTOs go out before
the tick's own frames. In lockstep the engine frames are then those of a node without a master.
Before the first sensor frame (no tick runs yet) it is served as the frames come.

Another ECU on the bus (:meth:`EcuNode.watch_bus`): a bus never hands a node its own frames
(SocketCAN does not loop a socket's frames back to it, the loopback multicast bus drops its
own), so a frame of an ID this ECU sends is another sender's: another ECU answering on the same
bus. Watched, the node listens for :data:`LISTEN_S` before its first tick in real time; one that
hears another ECU before it has flown for :data:`YOUNG_S` stays silent from then on
(``refused`` says why), and one that has flown longer reports it (``report``, the service
port's fault log) and goes on flying its engine.

The node reuses its buffers: nothing it keeps grows per frame or per tick.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from ecu import modes as M
from ecu.firmware import E2E_NONEWDATA, E2E_OK, E2E_WRONGCRC, Ecu, EcuInputs
from ecu.firmware_params import FirmwareParams
from ecu.params import EcuParams
from protocol.codec import Codec
from protocol.lockstep import TICK_MODULO, every_ticks
from protocol.node import SendFn

if TYPE_CHECKING:
    from ecu.service.logbook_save import LogbookSaver
    from ecu.service.port import ServicePort
    from ecu.xcp.slave import XcpSlave

_TELEMETRY_FIELDS = (
    "ap21_q24", "ap22_q24", "lambda_q24", "theta21_q24", "theta22_q24",
    "kx1_q24", "kx2_q24", "kr_q24", "kf1_q24", "kf2_q24",
)  # fmt: skip
TELEMETRY_COUNT = 13  # EcuTelemetry mux indices 0..12 (DBC)
RECEIVED = ("PlantSensors", "PlantAnalog", "Demand")  # the frames the ECU node takes
SENT = ("EcuActuator", "EcuStarter", "EcuStatus", "EcuTelemetry")  # the frames it sends
LISTEN_S = 0.03  # watched, real time: the node listens this long before its first tick (a
# flying ECU sends EcuActuator every period; the engine's pump watchdog waits 10 periods)
YOUNG_S = 0.5  # another ECU heard before the node has flown this long: the node stays silent
QUIET_S = 1.0  # another ECU heard again after this long unheard: reported again


def _clamp(x: int, lo: int, hi: int) -> int:
    return lo if x < lo else hi if x > hi else x


def _ahead(tick: int, now: int) -> bool:
    """``tick`` is after ``now`` (16-bit lockstep ticks)."""
    return 0 < (tick - now) % TICK_MODULO < TICK_MODULO // 2


SERVICE_IDLE_POLL_S = 0.02  # lockstep with no plant yet: the service port's poll period


class OtherEcuWatch:
    """Another ECU on the bus, told by the frames of the IDs this ECU sends (see the module
    docstring); shared by the Python and the C node. ``report(text)`` is told when another ECU
    is first heard, and again once heard after QUIET_S unheard."""

    def __init__(
        self, codec: Codec, rate_hz: int, lockstep: bool, report: Callable[[str], None]
    ) -> None:
        self.names = {codec[m].frame_id: m for m in SENT}
        self.young_ticks = math.ceil(YOUNG_S * rate_hz)
        self.listen_periods = 0 if lockstep else math.ceil(LISTEN_S * rate_hz)  # before tick 0
        self.quiet_ticks = max(1, math.ceil(QUIET_S * rate_hz))
        self.report = report
        self.frames = 0  # another ECU's frames heard
        self.reports = 0
        self.refused: str | None = None  # why the node stays silent, once it does
        self._last_tick = 0

    def period(self) -> bool:
        """Real time, one period of the node's clock: True while the node only listens (before
        its first tick) or stays silent (refused)."""
        if self.listen_periods > 0:
            self.listen_periods -= 1
            return True
        return self.refused is not None

    def heard(self, frame_id: int, ticks: int) -> None:
        """A frame of one of this ECU's IDs, heard after ``ticks`` ticks of the node's."""
        self.frames += 1
        what = f"{self.names[frame_id]} (0x{frame_id:03X})"
        if self.refused is None and ticks < self.young_ticks:
            self.refused = (
                f"another ECU is on the bus: its {what} heard before this ECU flew the engine; "
                "this ECU stays silent (one ECU per bus)"
            )
            self.reports += 1
            self.report(self.refused)
        elif self.refused is None and (
            self.reports == 0 or ticks - self._last_tick > self.quiet_ticks
        ):
            self.reports += 1
            self.report(
                f"another ECU is on the bus: {what} from another sender; this ECU goes on "
                "flying the engine (one ECU per bus: stop the other)"
            )
        self._last_tick = ticks

    def summary(self) -> dict:
        """The run summary's figures: another ECU's frames heard, and whether this one refused."""
        return {"other_ecu_frames": self.frames, "other_ecu_refused": self.refused is not None}


class EcuNode:
    """The firmware on the bus. ``lockstep`` selects the clocking (see the module docstring);
    ``max_ticks`` makes the node finish after answering that many ticks (None: run until
    stopped)."""

    def __init__(
        self,
        params: EcuParams | FirmwareParams | None = None,
        *,
        ecu: Ecu | None = None,
        lockstep: bool = True,
        max_ticks: int | None = None,
        codec: Codec | None = None,
    ) -> None:
        # the tick implementation: the Python firmware from params, or one given (ecu.port: C)
        self.ecu = ecu if ecu is not None else Ecu(params)
        self.rate_hz = self.ecu.p.rate_hz
        self.lockstep = lockstep
        self.max_ticks = max_ticks
        codec = codec or Codec()
        self.sensors, self.analog, self.demand = (codec[m] for m in RECEIVED)
        self.actuator = codec["EcuActuator"]
        self.starter = codec["EcuStarter"]
        self.status = codec["EcuStatus"]
        self.telemetry = codec["EcuTelemetry"]
        self.frame_ids = tuple(m.frame_id for m in (self.sensors, self.analog, self.demand))
        # checkers classify each frame (one lost frame before a good one is tolerated: the good
        # one is fresh); timeouts are counted by the firmware, in ticks
        self.sensors_check = self.sensors.checker(max_delta=2)
        self.analog_check = self.analog.checker(max_delta=2)
        self.demand_check = self.demand.checker(max_delta=2)
        self.every_status = every_ticks(self.status.cycle_time_ms, self.rate_hz)
        self.every_telemetry = every_ticks(self.telemetry.cycle_time_ms, self.rate_hz)
        self.every_demand = every_ticks(self.demand.cycle_time_ms, self.rate_hz)
        self.i = EcuInputs()
        self.i.sensor_status = self.i.analog_status = self.i.demand_status = E2E_NONEWDATA
        self._sensor_raw = [0] * len(self.sensors.signal_names)
        self._analog_raw = [0] * len(self.analog.signal_names)
        # the Demands held until their tick: the earliest, and one with a later DemandTick
        self._demand_raw = [0] * len(self.demand.signal_names)
        self._demand_next = [0] * len(self.demand.signal_names)
        self._actuator_raw = [0] * len(self.actuator.signal_names)
        self._starter_raw = [0] * len(self.starter.signal_names)
        self._status_raw = [0] * len(self.status.signal_names)
        self._telemetry_raw = [0, 0]
        self.ticks = 0  # ticks run
        self.tick = 0  # tick number being answered (lockstep: SensorTick)
        self.telemetry_index = 0
        self._starter_on = False  # a bench test drove the starter or igniter in OFF last tick
        self.ticked_demands = False  # the command node sends Demand frames with their tick
        self.demand_tick = -1  # DemandTick of the last valid Demand
        self.demand_pending = 0  # valid Demands not yet handed to the firmware (0, 1 or 2)
        self.applied_tick = -1  # DemandTick of the last Demand handed to the firmware
        self.waiting = False  # a sensor frame waits for its Demand (lockstep)
        self.demand_waits = 0  # ticks run without their due Demand after the guard time
        self.sensor_seen = False  # a sensor frame has come (the plant is, or was, alive)
        self.late_sensor_frames = 0  # lockstep: sensor frames of a tick already run
        self._timeout_s: float | None = None  # set while the plant is silent (see on_timeout)
        self.finished = False
        # the service port (ecu.service.port.ServicePort), polled before each tick, or None
        self.service: ServicePort | None = None
        self.xcp: XcpSlave | None = None  # the XCP slave (attach_xcp), or None
        # the logbook's save at rest (ecu.service.logbook_save), after each tick, or None
        self.logbook_saver: LogbookSaver | None = None
        self._xcp_send: Callable[[bytes], None] | None = None
        self._xcp_send_for: SendFn | None = None
        self.watch: OtherEcuWatch | None = None  # another ECU on the bus (watch_bus), or None
        self._codec = codec

    def watch_bus(self, report: Callable[[str], None]) -> None:
        """Watch for another ECU on the bus (see the module docstring): its frames are heard
        from now on; ``report(text)`` says what was heard and what this ECU does, and the
        service port's fault log has it; a refusal ends the node."""

        def other_ecu(text: str) -> None:
            report(text)
            if self.service is not None:
                self.service.note_other_ecu()
            self.finished = self.finished or watch.refused is not None

        self.watch = watch = OtherEcuWatch(self._codec, self.rate_hz, self.lockstep, other_ecu)
        self.frame_ids = (*self.frame_ids, *watch.names)

    def attach_xcp(self, slave: XcpSlave) -> None:
        """Put an XCP slave on the node: its command frames are heard from now on."""
        self.xcp = slave
        self.frame_ids = (*self.frame_ids, slave.cmd_id)

    def _xcp_sender(self, send: SendFn) -> Callable[[bytes], None]:
        """``send`` for the XCP slave's packets, on its response ID (made once per driver)."""
        if self._xcp_send is None or self._xcp_send_for is not send:
            res_id = self.xcp.res_id  # type: ignore[union-attr]
            self._xcp_send = lambda data: send(res_id, data)
            self._xcp_send_for = send
        return self._xcp_send

    # -- frames in ---------------------------------------------------------------------------
    def start(self, send: SendFn) -> None:
        pass

    def on_frame(self, frame_id: int, data: bytes | bytearray, send: SendFn) -> None:
        watch = self.watch
        if watch is not None and (frame_id in watch.names or watch.refused is not None):
            if frame_id in watch.names:
                watch.heard(frame_id, self.ticks)
            return  # (a node that refused takes nothing more)
        i = self.i
        if frame_id == self.sensors.frame_id:
            self.sensor_seen = True
            status = self.sensors_check.check(data)
            if i.sensor_status != E2E_OK:  # an OK frame since the last tick wins
                i.sensor_status = status
            tick = (self.tick + 1) % TICK_MODULO  # a corrupt frame: taken as the next tick's
            if status != E2E_WRONGCRC:  # the CRC holds: the tick is the sender's
                raw = self._sensor_raw
                self.sensors.unpack_raw(data, raw)
                tick = raw[0]
                if status == E2E_OK:
                    i.speed_rpm = raw[1]
                    i.egt_dk = raw[2]
            if self.lockstep:
                if self.ticks > 0 and not _ahead(tick, self.tick):
                    # a tick already run (on the node's own clock, or a repeated frame): its
                    # values go to the next tick, as a frame between ticks does in real time
                    self.late_sensor_frames += 1
                    return
                self.timeout_s = None
                self.tick = tick
                if self.ticked_demands and self._demand_due():
                    self.waiting = True
                else:
                    self._run_tick(send)
        elif frame_id == self.analog.frame_id:
            status = self.analog_check.check(data)
            if status == E2E_OK:
                raw = self._analog_raw
                self.analog.unpack_raw(data, raw)
                i.supply_mv = raw[1]
                i.pump_ma = raw[2]
            if i.analog_status != E2E_OK:  # an OK frame since the last tick wins
                i.analog_status = status
        elif frame_id == self.demand.frame_id:
            status = self.demand_check.check(data)
            if status == E2E_OK:
                self.ticked_demands = self.lockstep
                self._hold_demand(data)
            elif i.demand_status != E2E_OK:
                i.demand_status = status
            if self.waiting and not self._demand_due():
                self._run_tick(send)
        elif self.xcp is not None and frame_id == self.xcp.cmd_id:
            self.xcp.receive(data)
            if self.lockstep and not self.sensor_seen:  # no tick yet: served as it comes
                self.xcp.serve(self._xcp_sender(send))

    def _hold_demand(self, data: bytes | bytearray) -> None:
        """Keep a valid Demand until its DemandTick (at once when unticked). Two are held, so
        that the next one arriving before the present one's tick has run (the ECU ticking late,
        on its own clock while sensor frames are lost) does not overwrite it; a third replaces
        the later of the two."""
        if self.demand_pending == 0 or not self.ticked_demands:
            self.demand.unpack_raw(data, self._demand_raw)
            self.demand_pending = 1
        else:
            self.demand.unpack_raw(data, self._demand_next)
            if _ahead(self._demand_next[4], self._demand_raw[4]):
                self.demand_pending = 2
            else:  # the same or an earlier tick: it replaces the one held
                self._demand_raw, self._demand_next = self._demand_next, self._demand_raw
                self.demand_pending = 1
        self.demand_tick = (self._demand_next if self.demand_pending == 2 else self._demand_raw)[4]

    def _demand_due(self) -> bool:
        """Lockstep: a Demand is due at this tick and the one carrying this tick has not come."""
        if not self.ticked_demands or self.tick % self.every_demand != 0:
            return False
        tick = self.tick
        held = (self.demand_pending >= 1 and self._demand_raw[4] == tick) or (
            self.demand_pending == 2 and self._demand_next[4] == tick
        )
        return not held and self.applied_tick != tick

    @property
    def timeout_s(self) -> float | None:
        """Lockstep silence before ``on_timeout`` (None: the driver's guard). Before the first
        sensor frame a node with a service port or an XCP slave polls it every
        SERVICE_IDLE_POLL_S."""
        return SERVICE_IDLE_POLL_S if self.polling else self._timeout_s

    @property
    def polling(self) -> bool:
        """Lockstep, no plant heard yet: the node polls its service port or XCP slave (idle
        polls, not guard timeouts)."""
        idle = self.service is not None or self.xcp is not None
        return self._timeout_s is None and idle and not self.sensor_seen

    @timeout_s.setter
    def timeout_s(self, value: float | None) -> None:
        self._timeout_s = value

    def on_timeout(self, send: SendFn) -> None:
        """Lockstep guard time passed: run the waiting tick without its Demand; or, when the
        plant has fallen silent, tick on the node's own clock (one tick per period of silence)
        so that the firmware counts the lost sensor frames and reacts within its ticks; or,
        with no plant heard yet, serve the service port with the engine stopped (no tick runs:
        a real ECU answers its port before its engine turns)."""
        if self.watch is not None and self.watch.refused is not None:
            return
        if self.waiting:
            self.demand_waits += 1
            self._run_tick(send)
        elif self.lockstep and self.sensor_seen:
            self.timeout_s = 1.0 / self.rate_hz
            self.tick = (self.tick + 1) % TICK_MODULO
            self._run_tick(send)
        else:
            if self.service is not None:
                self.service.poll(self.i, ticking=False)
            if self.xcp is not None:
                self.xcp.serve(self._xcp_sender(send))

    def on_period(self, send: SendFn) -> None:
        """Real time: one tick per period of the node's own clock (watched: none while it
        listens for another ECU, or once it refused)."""
        if self.watch is not None and self.watch.period():
            return
        self.tick = self.ticks % TICK_MODULO
        self._run_tick(send)

    # -- tick and frames out -----------------------------------------------------------------
    def _apply_demand(self) -> None:
        """Hand the latest held Demand whose tick has come to the firmware (at once if
        unticked); one still ahead stays held. Only while one is held (``demand_pending``)."""
        if self.ticked_demands:
            if _ahead(self._demand_raw[4], self.tick):
                return  # DemandTick still ahead
            if self.demand_pending == 2 and not _ahead(self._demand_next[4], self.tick):
                self._demand_raw, self._demand_next = self._demand_next, self._demand_raw
                self.demand_pending = 1  # both due: the later one wins
        raw = self._demand_raw
        i = self.i
        i.arm = raw[0]
        i.stop = raw[1]
        i.demand_cpct = raw[2]
        i.open_loop_mv = raw[3]
        i.demand_status = E2E_OK
        self.applied_tick = raw[4]
        if self.demand_pending == 2:
            self._demand_raw, self._demand_next = self._demand_next, self._demand_raw
        self.demand_pending -= 1

    def _run_tick(self, send: SendFn) -> None:
        self.waiting = False
        i = self.i
        if self.demand_pending:
            self._apply_demand()
        i.tick = self.tick
        xcp = self.xcp
        if xcp is not None:
            xcp.serve(self._xcp_sender(send))  # the master's requests, at the tick boundary
        # the service port (or else the XCP slave) may be the demand source (a bench): it
        # gives the inputs to take
        if self.service is not None:
            o = self.ecu.tick(self.service.poll(i))
        elif xcp is not None:
            o = self.ecu.tick(xcp.inputs(i))
        else:
            o = self.ecu.tick(i)
        if xcp is not None:
            xcp.sample(self._xcp_sender(send))  # the DAQ lists of this tick's events
        if self.logbook_saver is not None:
            self.logbook_saver.after_tick()
        i.sensor_status = i.analog_status = i.demand_status = E2E_NONEWDATA
        k = self.ticks
        if k % self.every_status == 0:
            raw = self._status_raw
            raw[0] = o.mode
            raw[1] = o.fault_word
            raw[2] = _clamp(o.pump_health_pm, 0, 4095)
            raw[3] = o.owner
            raw[4] = _clamp(o.nref_cpct, 0, 15000)
            raw[5] = o.inputs_valid
            self.status.pack_raw(raw)
            send(self.status.frame_id, self.status.data)
        if k % self.every_telemetry == 0:
            raw = self._telemetry_raw
            j = self.telemetry_index
            raw[0] = j
            if j < 10:
                raw[1] = getattr(o, _TELEMETRY_FIELDS[j])
            elif j == 10:
                raw[1] = self.ecu.s.obs_n_q24  # fast-model speed deviation estimate (Q7.24)
            elif j == 11:
                raw[1] = self.ecu.s.obs_v_q24  # fast-model speed rate estimate (Q7.24)
            else:
                raw[1] = o.sat_events
            self.telemetry.pack_raw(raw)
            send(self.telemetry.frame_id, self.telemetry.data)
            self.telemetry_index = j + 1 if j + 1 < TELEMETRY_COUNT else 0
        drive = o.mode == M.OFF and (o.starter_cpct > 0 or o.igniter)
        if o.mode == M.ARMED or o.mode == M.SHUTDOWN or drive or self._starter_on:
            raw = self._starter_raw
            raw[0] = o.igniter
            raw[1] = self.tick
            raw[2] = _clamp(o.starter_cpct, 0, 10000)
            raw[3] = o.seq_state
            raw[4] = o.seq_reason
            self.starter.pack_raw(raw)
            send(self.starter.frame_id, self.starter.data)
        self._starter_on = drive  # a test's outputs in OFF: one more frame says they ended
        raw = self._actuator_raw
        raw[0] = o.pump_enable
        raw[1] = o.mode
        raw[2] = self.tick
        raw[3] = o.duty_cpct
        raw[4] = _clamp(o.pump_mv, 0, 30000)
        self.actuator.pack_raw(raw)
        send(self.actuator.frame_id, self.actuator.data)
        self.ticks = k + 1
        if self.max_ticks is not None and self.ticks >= self.max_ticks:
            self.finished = True
