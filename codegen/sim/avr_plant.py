"""Run an ATmega2560 image with heaters in simavr against thermal plants, and say how each heater did.

The harness (simavr_harness.c with simavr_plant.c) integrates a first-order plant per heater on simulated time,
with the power the heater's PWM registers give, and feeds the thermistor divider's voltage to the ADC; faults
are injected at simulated times. Its trace gives the plant's temperature every 0.1 s, every ADC reading the
firmware took and every duty change; the firmware's own status bytes say whether, why and where it tripped.
"""

from __future__ import annotations

import array
import subprocess
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from codegen import progress
from codegen.errors import BuildError
from codegen.firmware.avr.board import board_pins, parse_pin
from codegen.firmware.avr.heaters import HEATERS_FAULT_BIT, PWM_CHANNELS, adc_channel
from codegen.firmware.avr.player import START_TICKS
from codegen.firmware.config import FirmwareConfig, load_target
from codegen.heaters.control import PID_PERIOD_S
from codegen.heaters.plant import Plant, heating_figures
from codegen.heaters.protection import REASONS
from codegen.heaters.sensors import SensorSpec, millivolts
from codegen.sim.avr import (EXIT_STATES, SimTrace, _homing_fault, decode_edges, harness_binary, run_harness,
                             simulated_s, switch_args, timer_ticks0, watched_pins)
from codegen.sim.avr_edges import EDGE_RECORD, read_edges

FAULTS = {"thermistor-open": "open", "thermistor-short": "short", "heater-dead": "dead",
          "thermistor-loose": "loose"}
MV_TABLE_C = (-40.0, 0.5, 1081)  # the divider's millivolts from -40 degC every 0.5 degC to 500 degC
SETTLE_S = 30.0  # the band is measured from this long after the target is first reached
# Data-space addresses of the PWM registers by timer and channel: OCR (its low byte), TCCRnA, COMnx1's mask.
PWM_REGISTERS = {(2, "A"): (0xB3, 0xB0, 0x80), (2, "B"): (0xB4, 0xB0, 0x20), (4, "A"): (0xA8, 0xA0, 0x80),
                 (4, "B"): (0xAA, 0xA0, 0x20), (4, "C"): (0xAC, 0xA0, 0x08)}
PORTS = {"A": 0x22, "B": 0x25, "C": 0x28, "D": 0x2B, "E": 0x2E, "F": 0x31, "G": 0x34, "H": 0x102, "J": 0x105,
         "K": 0x108, "L": 0x10B}


@dataclass(frozen=True)
class HeaterPlant:
    """The simulated heater behind one of config.heaters: its plant and its thermistor."""

    plant: Plant
    sensor: SensorSpec = "EPCOS 100K B57560G104F"
    pullup_ohm: float = 4700.0
    start_c: float | None = None  # the plant's temperature at power-up; None: ambient


@dataclass(frozen=True)
class Fault:
    heater: str
    kind: str  # a key of FAULTS
    at_s: float


@dataclass
class HeaterTrace:
    """One heater: the plant every 0.1 s, the firmware's readings and the duty it set in each period."""

    time_s: np.ndarray  # samples
    temp_c: np.ndarray
    duty: np.ndarray  # the PWM's duty at the samples, 0..1
    read_s: np.ndarray  # each ADC reading the firmware took (one per control period)
    reading: np.ndarray
    period_duty: np.ndarray  # the duty (0..255) the firmware set after each reading, before the next


@dataclass
class HeaterRun:
    state: str  # done (the firmware halted) | budget (still running at the end) | held (`held_after_s`)
    seconds: float  # simulated
    heaters: dict[str, HeaterTrace]
    trip: str | None  # the reason the firmware stopped the machine, one of REASONS
    trip_heater: str | None
    trip_s: float | None
    heater_pins_low: bool  # at the end: every heater's PWM disconnected and its pin low
    steppers_stopped: bool  # at the end: Timer1 off and every driver disabled
    stage_max_cycles: int  # the longest heater stage while the table played (heaters_poll's call), 0: none
    stages: int  # how many stages ran while the table played
    steps: SimTrace
    fan: np.ndarray  # (K, 2): the fan's duty (0..1) from each simulated time (s) on; [[0, 0]] at power-up


def _stage_address(hex_path: Path) -> int | None:
    """heaters_poll's byte address in the ELF beside the image (firmware.elf), if any."""
    elf = Path(hex_path).with_suffix(".elf")
    if not elf.is_file():
        return None
    symbols = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True).stdout.split("\n")
    return next((int(line.split()[0], 16) for line in symbols if line.endswith(" heaters_poll")), None)


def _plant_file(config: FirmwareConfig, plants: dict[str, HeaterPlant], faults, f_cpu: int, log: Path,
                stage: int | None) -> str:
    names = [h.name for h in config.heaters]
    if set(plants) != set(names):
        raise ValueError(f"plants for {sorted(plants)}, the config has heaters {names}")
    first, step, n = MV_TABLE_C
    lines = [f"log {log}", "avcc 5000", f"sample {round(PID_PERIOD_S * f_cpu)}"]
    lines += [f"stage {stage:x}"] if stage is not None else []
    fan = load_target(config.board).get("fan")
    if fan and fan not in {h.pwm_pin for h in config.heaters} and fan in PWM_CHANNELS:
        pin, pwm = parse_pin(fan), PWM_CHANNELS[fan]
        ocr, tccra, com = PWM_REGISTERS[pwm["timer"], pwm["channel"]]
        lines.append(f"fan {ocr:x} {tccra:x} {com:x} {PORTS[pin.port]:x} {pin.bit}")
    for h in config.heaters:
        hp, pwm = plants[h.name], PWM_CHANNELS[h.pwm_pin]
        ocr, tccra, com = PWM_REGISTERS[pwm["timer"], pwm["channel"]]
        pin, p = parse_pin(h.pwm_pin), hp.plant
        mv = millivolts(hp.sensor, first + step * np.arange(n), hp.pullup_ohm)
        start = p.ambient_c if hp.start_c is None else hp.start_c
        lines.append(f"heater {adc_channel(parse_pin(h.sensor_pin))} {ocr:x} {tccra:x} {com:x} {PORTS[pin.port]:x} "
                     f"{pin.bit} {p.capacity_j_per_k!r} {p.loss_w_per_k!r} {p.heater_w!r} {p.ambient_c!r} {start!r} "
                     f"{first!r} {step!r} {n}\n" + " ".join(f"{v:.4f}" for v in mv))
    for f in faults:
        if f.kind not in FAULTS or f.heater not in names:
            raise ValueError(f"unknown fault {f.kind}@{f.heater} (faults: {', '.join(FAULTS)})")
        lines.append(f"fault {names.index(f.heater)} {FAULTS[f.kind]} {round(f.at_s * f_cpu)}")
    return "\n".join(lines) + "\n"


def _logged_s(log: Path, f_cpu: int) -> float | None:
    """Simulated seconds at the last whole line of the plant trace the harness is writing (a heat-up steps no
    motor: its edges file stands still)."""
    lines = progress.tail(log).split(b"\n")[:-1]
    fields = lines[-1].split() if lines else []
    return int(fields[1]) / f_cpu if len(fields) > 1 and fields[0] in (b"A", b"D", b"S", b"F") else None


def read_trace(path: Path, n: int, f_cpu: int) -> tuple[dict, dict]:
    """The plant trace: per heater its samples, readings and duties, and the end's records. Read a line at a time
    into packed columns (an 11-hour print has millions of rows: as Python lists they took hundreds of MB)."""
    widths = {"A": 3, "D": 3, "S": 4, "F": 2}
    columns = {kind: array.array("d") for kind in widths}
    end: dict = {"P": {}, "H": {}}
    with path.open(encoding="ascii") as lines:
        for line in lines:
            kind, *v = line.split()
            if kind in columns:
                columns[kind].extend(map(float, v))
            elif kind in ("P", "H"):
                end[kind][v[0] if kind == "P" else int(v[0])] = int(v[1])
            else:
                end[kind] = [int(x) for x in v]
    rows = {kind: np.frombuffer(columns[kind], dtype=float).reshape(-1, width) for kind, width in widths.items()}
    per = {}
    for k in range(n):
        s, a = (rows[kind][rows[kind][:, 1] == k] for kind in ("S", "A"))
        d = np.concatenate([[[0, k, 0]], rows["D"][rows["D"][:, 1] == k]])  # off at power-up
        # The duty of each period: the last change before the next reading (the 8-bit duty: 256 is 255).
        nxt = np.append(a[1:, 0], np.inf)
        duty256 = d[np.searchsorted(d[:, 0], nxt, side="left") - 1, 2]
        per[k] = HeaterTrace(s[:, 0] / f_cpu, s[:, 2], s[:, 3] / 256, a[:, 0] / f_cpu, a[:, 2].astype(np.int64),
                             np.minimum(duty256, 255).astype(np.int64))
    end["F"] = np.concatenate([[[0.0, 0.0]], rows["F"] / [f_cpu, 256]])
    return per, end


def simulate_heaters(hex_path: Path, config: FirmwareConfig, seconds: float, plants: dict[str, HeaterPlant],
                     faults: tuple[Fault, ...] = (), switches: dict[int, int | None] | None = None,
                     held_after_s: float | None = None, presses: list[tuple[str, int, int]] = (),
                     beside=None) -> HeaterRun:
    """Run `hex_path` with a plant behind each heater for `seconds` of simulated time, or until it halts (the
    table played and the heaters off, a protection trip, a failed homing), or with `held_after_s` until that long
    after the player started its timer (state "held": an image that holds its heaters after the table).
    `presses`: keys to ground held down, (pin such as PL2, from cycle, to cycle), as codegen/sim/avr.py's; `beside`
    as codegen/sim/avr.py simulate's (the run's steps then hold none of its records)."""
    pins = board_pins(config)
    mcu = load_target(pins.mcu)
    f_cpu, tick_hz = int(mcu["f_cpu"]), int(mcu["tick_hz"])
    switches = {k: 0 for k in range(len(config.homing))} if switches is None else switches
    with tempfile.TemporaryDirectory(prefix="printer-codegen-plant-") as tmp:
        edges, log, spec = Path(tmp) / "edges.bin", Path(tmp) / "trace.txt", Path(tmp) / "plant.txt"
        spec.write_text(_plant_file(config, plants, faults, f_cpu, log, _stage_address(hex_path)))
        held = [] if held_after_s is None else [f"held={round(held_after_s * f_cpu)}"]
        cmd = [str(harness_binary()), pins.mcu, str(f_cpu), str(hex_path), str(edges), str(round(seconds * f_cpu)),
               f"plant={spec}", *held, *switch_args(config, switches),
               *(f"key={pin[1:]},{a},{b}" for pin, a, b in presses), *watched_pins(config)]
        with progress.stage("simulate", seconds, "s simulated", 1) as bar:
            if beside is None:
                done = progress.run_watched(cmd, bar, lambda _: max(simulated_s(edges, f_cpu) or 0.0,
                                                                     _logged_s(log, f_cpu) or 0.0))
            else:
                done = run_harness(cmd, bar, edges, f_cpu, beside)
        if done.returncode not in EXIT_STATES or done.returncode == 1:
            raise BuildError(f"simavr harness failed on {hex_path}:\n{(done.stderr + done.stdout).strip()}")
        rec = read_edges(edges) if beside is None else np.zeros(0, EDGE_RECORD)
        per, end = read_trace(log, len(config.heaters), f_cpu)
    fields = dict(kv.split("=", 1) for kv in done.stdout.strip().splitlines()[-1].split())
    state, cycles = EXIT_STATES[done.returncode], int(fields["cycles"])
    status, reason, which = (int(fields[k]) for k in ("status", "status1", "status2"))
    tripped = bool(status >> HEATERS_FAULT_BIT & 1) and state == "done"
    timer_start = int(fields["timer_start"])
    tick0 = timer_start + START_TICKS * (f_cpu // tick_hz) if timer_start >= 0 else None
    homing = None if tripped else _homing_fault(config, status, reason, which)  # the same status bytes
    steps = replace(decode_edges(rec, config, state, cycles, tick0, homing),
                    resumes=tuple(timer_ticks0(fields, f_cpu, tick_hz)[1:]))
    pins_low, stopped = stopped_safely(end, config)
    return HeaterRun(state=state, seconds=cycles / f_cpu,
                     heaters={h.name: per[k] for k, h in enumerate(config.heaters)},
                     trip=REASONS[reason - 1] if tripped else None,
                     trip_heater=config.heaters[which].name if tripped else None,
                     trip_s=cycles / f_cpu if tripped else None, heater_pins_low=pins_low,
                     steppers_stopped=stopped,
                     stage_max_cycles=end["I"][0], stages=end["I"][1], steps=steps, fan=end["F"])


def stopped_safely(end: dict, config: FirmwareConfig) -> tuple[bool, bool]:
    """From the plant trace's end state (read_trace): every heater's PWM disconnected and its pin low; Timer1 off
    and every stepper driver disabled."""
    pins = board_pins(config)
    tccr1b, timsk1 = end["T"]
    disabled = all((end["P"][w.enable.port] >> w.enable.bit & 1) == int(pins.enable_active_low) for w in pins.motors)
    return all(end["H"][k] == 0 for k in range(len(config.heaters))), (tccr1b & 7) == 0 and timsk1 == 0 and disabled


def heater_summary(run: HeaterRun, name: str, target_c: float, settle_s: float = SETTLE_S,
                   band_from_s: float | None = None, since_s: float = 0.0) -> dict:
    """verify's figures for one heater from simulated time `since_s` (when its target was set) on: target_c,
    time_to_target_s (first within 1 degC, from since_s), overshoot_c, band_c (the largest distance from the target
    from settle_s after reaching it, or with `band_from_s` from that simulated time, the end of a wait for it, once
    it has reached it),
    trip (None or the reason)."""
    h = run.heaters[name]
    after = h.time_s >= since_s
    figures = heating_figures(SimpleNamespace(time_s=h.time_s[after] - since_s, temp_c=h.temp_c[after]), target_c,
                              settle_s)  # reads those two
    band = figures.band_c
    if band_from_s is not None and figures.time_to_target_s is not None:
        after = h.time_s >= max(band_from_s, since_s + figures.time_to_target_s)  # holding it: reached, waited for
        band = float(np.abs(h.temp_c[after] - target_c).max()) if after.any() else None
    return {"target_c": target_c, "time_to_target_s": figures.time_to_target_s, "overshoot_c": figures.overshoot_c,
            "band_c": band, "trip": run.trip if run.trip_heater in (None, name) else None}
