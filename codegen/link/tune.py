"""The host's side of `printer-codegen tune`: the tune firmware's frames (templates/avr/tune.c.j2) and a session
that runs Marlin's relay on the real heater (over pyserial) or the simulated one (codegen/sim/avr_tune.py).

Frames are the link protocol's (codegen/link/protocol.py: SYNC, LEN, SEQ, TYPE, payload, CRC-16), with types of
their own; little-endian payloads, deci-degrees (0.1 degC), periods of 0.1 s.
Host to firmware (the firmware takes any SEQ):
    HELLO   0x02  asks for READY
    START   0x10  target i16, bias u8, d u8: the relay begins, heating at bias + d
    SET     0x11  bias u8, d u8: the next cycle's relay (the heating phase that has just begun takes them at once)
    OFF     0x12  the heater off; STOPPED answers
Firmware to host:
    READY   0x90  heater index u8 (0 hotend, 1 bed), maximum i16, the relay's dwell u8 (periods)
    STARTED 0x91  the relay runs
    SWITCH  0x92  period u32, heating u8 (the phase that begins), length u16 (periods of the one that ended),
                  extreme i16 (codegen/heaters/tuning.py's Switch), the new phase's duty u8
    TEMP    0x93  period u32, reading i16, duty u8: every second while the relay runs
    TRIP    0x94  reason u8 (1 + codegen.heaters.protection.REASONS' index), reading i16, period u32: the heater is
                  off until reset; repeated in answer to any frame
    STOPPED 0x95  period u32: the heater is off (OFF's answer)
"""

from __future__ import annotations

import signal
import struct
import time
from dataclasses import dataclass, field
from typing import Optional

from codegen.heaters.control import PWM_MAX
from codegen.heaters.protection import REASONS
from codegen.heaters.tuning import Relay, RelayCycle, Switch
from codegen.link import protocol

HELLO, START, SET, OFF = 0x02, 0x10, 0x11, 0x12
READY, STARTED, SWITCH, TEMP, TRIP, STOPPED = range(0x90, 0x96)
FRAME_TYPES = {"T_HELLO": HELLO, "T_START": START, "T_SET": SET, "T_OFF": OFF, "T_READY": READY,
               "T_STARTED": STARTED, "T_SWITCH": SWITCH, "T_TEMP": TEMP, "T_TRIP": TRIP, "T_STOPPED": STOPPED}
HEATER_NAMES = ("hotend", "bed")  # READY's heater index
HELLO_EVERY_S = 0.25  # HELLO again until READY (an Arduino's bootloader runs for a second or two after reset)
ANSWER_S = 2.0  # how long START and OFF may go unanswered
READY_S = 10.0  # how long HELLOs may go unanswered: then the board does not run the tune firmware
READ_SLICE_S = 0.05  # the longest a read of the port waits before the session looks at Ctrl-C and its timers


@dataclass
class TuneHost:
    """A tune session: HELLO until READY, START, the relay's cycles, OFF. Drive it with transmit(now) / receive(data,
    now) / wake_at() (seconds on any clock) until `done`; `outcome`: finished | tripped | stopped (Ctrl-C) | failed.
    """

    heater: str
    target_c: float
    cycles: int = 5
    max_duty: int = PWM_MAX
    relay: Relay = field(init=False)
    outcome: Optional[str] = None
    trip: Optional[str] = None  # the protection's reason
    error: Optional[str] = None
    temps: list[tuple[float, float, int]] = field(default_factory=list)  # (period s, reading degC, duty) each second
    switches: list[Switch] = field(default_factory=list)
    _out: bytearray = field(default_factory=bytearray)
    _parser: protocol.Parser = field(default_factory=lambda: protocol.Parser(protocol.MAX_ANSWER))
    _seq: int = 0
    _phase: str = "hello"  # hello | starting | running | stopping
    _deadline: float = 0.0
    _first_hello: Optional[float] = None
    _ending: str = "stopped"  # the outcome once STOPPED arrives

    def __post_init__(self):
        self.relay = Relay(self.max_duty)

    @property
    def done(self) -> bool:
        return self.outcome is not None

    @property
    def cycles_done(self) -> int:
        return len(self.relay.cycles)

    def _send(self, kind: int, payload: bytes = b"") -> None:
        self._out += protocol.frame(kind, self._seq, payload)
        self._seq += 1

    def stop(self, now: float, outcome: str = "stopped") -> None:
        """The heater off (OFF), then the session ends with `outcome` once STOPPED arrives."""
        if self._phase != "stopping":
            self._send(OFF)
            self._phase, self._deadline, self._ending = "stopping", now + ANSWER_S, outcome

    def transmit(self, now: float) -> bytes:
        if self._phase == "hello" and now >= self._deadline:
            self._first_hello = now if self._first_hello is None else self._first_hello
            if now - self._first_hello > READY_S:
                self.error, self.outcome = f"no answer to HELLO within {READY_S:g} s: flash the tune firmware", "failed"
            self._send(HELLO)
            self._deadline = now + HELLO_EVERY_S
        elif self._phase in ("starting", "stopping") and now >= self._deadline and not self.done:
            self.error = f"the tune firmware did not answer {'START' if self._phase == 'starting' else 'OFF'}"
            self.outcome = "failed"
        out, self._out = bytes(self._out), bytearray()
        return out

    def wake_at(self) -> Optional[float]:
        return None if self.done or self._phase == "running" else self._deadline

    def receive(self, data: bytes, now: float) -> None:
        for f in self._parser.feed(data):
            if not self.done:
                self._take(f, now)

    def _take(self, f: protocol.Frame, now: float) -> None:
        if f.kind == TRIP:
            reason, _reading, _period = struct.unpack_from("<BhI", f.payload)
            self.trip = REASONS[reason - 1] if 0 < reason <= len(REASONS) else f"reason {reason}"
            self.outcome = "tripped"
        elif f.kind == protocol.IDENT:
            self.error, self.outcome = "the board runs the streaming firmware: flash the tune firmware", "failed"
        elif f.kind == READY and self._phase == "hello":
            index, max_dc, _dwell = struct.unpack_from("<BhB", f.payload)
            if HEATER_NAMES[index] != self.heater:
                self.error = f"the board runs the tune firmware of the {HEATER_NAMES[index]}, not the {self.heater}"
                self.outcome = "failed"
            elif round(self.target_c * 10) >= max_dc:
                self.error = f"target {self.target_c:g} degC is not below the heater's maximum {max_dc / 10:g} degC"
                self.outcome = "failed"
            else:
                self._send(START, struct.pack("<hBB", round(self.target_c * 10), self.relay.bias, self.relay.d))
                self._phase, self._deadline = "starting", now + ANSWER_S
        elif f.kind == STARTED and self._phase == "starting":
            self._phase = "running"
        elif f.kind == TEMP:
            period, reading, duty = struct.unpack_from("<IhB", f.payload)
            self.temps.append((period / 10, reading / 10, duty))
        elif f.kind == SWITCH and self._phase == "running":
            period, heating, length, extreme, _duty = struct.unpack_from("<IBHhB", f.payload)
            switch = Switch(period, bool(heating), length, extreme)
            self.switches.append(switch)
            update = self.relay.switch(switch)
            if self.cycles_done >= self.cycles:
                self.stop(now, "finished")
            elif update is not None:
                self._send(SET, bytes(update))
        elif f.kind == STOPPED and self._phase == "stopping":
            self.outcome = self._ending

    def result(self) -> Optional[RelayCycle]:
        """The last full cycle (Marlin prints the gains of the last one), None before any."""
        return self.relay.cycles[-1] if self.relay.cycles else None


def heaters_snippet(controls: dict[str, dict]) -> str:
    """The job file's `heaters:` lines (under `machine:`) with each heater's control ({"pid": {kp, ki, kd}} or
    {"bang_bang": {hysteresis_c}}): a job with `heaters:` gets exactly the heaters it lists, so all of them."""
    lines = ["  heaters:"]
    for name, control in controls.items():
        (law, values), = control.items()
        inner = ", ".join(f"{k}: {v:.4g}" for k, v in values.items())
        lines += [f"    {name}:", f"      control: {{{law}: {{{inner}}}}}"]
    return "\n".join(lines) + "\n"


def run_serial(host: TuneHost, port, progress: bool = True) -> None:
    """Drive `host` over the open pyserial `port` in real time; Ctrl-C turns the heater off (OFF) and waits for
    STOPPED (a second Ctrl-C stops waiting)."""
    from tqdm import tqdm  # imported here, as pyserial: the other verbs never need it

    presses: list[float] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: presses.append(time.monotonic()))
    start = time.monotonic()
    bar = tqdm(total=host.cycles, unit="cycle", desc=f"tuning {host.heater}", disable=not progress,
               dynamic_ncols=True)
    try:
        while not host.done and len(presses) < 2:
            now = time.monotonic() - start
            if presses:
                host.stop(now)
            out = host.transmit(now)
            if out:
                port.write(out)
            port.timeout = READ_SLICE_S
            data = port.read(max(1, port.in_waiting))
            if data:
                host.receive(data, time.monotonic() - start)
            if host.temps:
                bar.set_postfix_str(f"{host.temps[-1][1]:.1f} degC")
            bar.update(host.cycles_done - bar.n)
    finally:
        if not host.done:  # a second Ctrl-C: one more OFF on the way out
            port.write(protocol.frame(OFF, 0))
        signal.signal(signal.SIGINT, previous)
        bar.close()
