"""The ATmega2560 heater runtime (templates/avr/heaters.c.j2, heaters.h.j2, heaters_hook.S.j2): a job's heaters
as FirmwareConfig.heaters (job_heaters: the board file's pins), the fan, and what the templates need from them.
The program's settings reach them as the table's runtime records (codegen/tables/runtime.py): the step interrupt keeps
the latest value of each, heaters.c applies them at its next period, and a WAIT holds the player until the
heaters of its mask have settled (SETTLE_WINDOW_DC for SETTLE_PERIODS).

The runtime adds no interrupt: Timer3 counts the 0.1 s control period in CTC mode (its compare flag, polled),
the ADC is started and polled, the heaters' MOSFETs are driven by hardware fast PWM (Timer2 OC2A, Timer4 OC4C at
61 Hz). A period's work is cut into stages (read a thermistor; check a heater's temperature and protection; its
control law in two halves). Before the table, main's loop runs them (and waits for the start sequence's M109 /
M190 heaters). While the table plays, every register belongs to the step interrupt, so main's idle loop
(player_isr.S) calls heaters_hook.S when a period is due or a stage pending; with interrupts off, the hook saves
the registers C may change and runs stages one after another only while Timer1's next compare is at least
SLICE_CYCLES away: no stage delays a step; the hook's check alone can (33 cycles at most).
"""

from __future__ import annotations

import math

from codegen.errors import BuildError
from codegen.firmware.avr.board import parse_pin
from codegen.firmware.config import FirmwareConfig, HeaterFirmware, load_target
from codegen.heaters.control import D_FILTER_SHIFT, PID_FUNCTIONAL_RANGE_DC, PID_PERIOD_S, FixedBangBang, FixedPid
from codegen.heaters.protection import REASONS
from codegen.program.heater_settings import HeaterSettings, heater_settings
from codegen.program.heaters import HeaterProgram
from codegen.tables.schedule import HEATER_COMMANDS, RT_FAN, RT_TARGET_BED, RT_TARGET_HOTEND, RT_WAIT, WAIT_MASKS

PERIOD_PRESCALE = 256  # Timer3's prescaler: 16 us ticks, 6250 per period
SETTLE_WINDOW_DC = 20  # M109 / M190: within +-2 degC of the target ...
SETTLE_PERIODS = 30  # ... for 3 s
SLICE_CYCLES = 400  # a stage (274 measured: tests/firmware/avr/test_heaters.py) and the hook around it (77 counted)
# The streaming firmware runs a stage with the link's interrupts on: room for two receive interrupts and a transmit
# one (targets/atmega2560.yaml: 121 cycles at the most each) that may come during it.
STREAM_SLICE_CYCLES = SLICE_CYCLES + 3 * 121
HOOK_SAVED = ("r20", "r21", "r22", "r23", "r24", "r25", "r26", "r27", "r30", "r31")  # call-used, the player's state
HEATERS_FAULT_BIT = 7  # GPIOR0: the heaters stopped the machine (GPIOR1: 1 + the reason's index, GPIOR2: heater)
HEATERS_BUSY_BIT = 6  # GPIOR0: a stage of the period is pending (the hook comes back for it)
TABLE_LINE = 12  # table entries per line of heaters.c
RUNTIME_COMMANDS = {"target_hotend": RT_TARGET_HOTEND, "target_bed": RT_TARGET_BED, "fan": RT_FAN, "wait": RT_WAIT}

# Hardware PWM outputs of the ATmega2560 that the boards use for MOSFETs: the timer and its channel, each timer
# in 8-bit fast PWM (TOP 0xFF, prescaler 1024: 61 Hz).
PWM_CHANNELS = {
    "PB4": {"timer": 2, "channel": "A"},  # D10: RAMPS hot end (E0)
    "PH6": {"timer": 2, "channel": "B"},  # D9: RAMPS fan / second hot end
    "PH5": {"timer": 4, "channel": "C"},  # D8: RAMPS bed
    "PH4": {"timer": 4, "channel": "B"},  # D7
    "PH3": {"timer": 4, "channel": "A"},  # D6
}
TIMER_SETUP = {
    2: {"tccra": "_BV(WGM21) | _BV(WGM20)", "tccrb": "_BV(CS22) | _BV(CS21) | _BV(CS20)",
        "what": "fast PWM, TOP 0xFF, prescaler 1024: 61 Hz"},
    4: {"tccra": "_BV(WGM40)", "tccrb": "_BV(WGM42) | _BV(CS42) | _BV(CS40)",
        "what": "fast PWM 8-bit (mode 5), TOP 0xFF, prescaler 1024: 61 Hz"},
}


def heater_firmware(settings: HeaterSettings, pins: tuple[str, str]) -> HeaterFirmware:
    """A job's heater (codegen.program.heater_settings) as the firmware's config, on the board's pins (MOSFET and
    thermistor: codegen.targets.board_heater_pins)."""
    pwm_pin, sensor_pin = pins
    return HeaterFirmware(settings.name, pwm_pin, sensor_pin, tuple(int(v) for v in settings.table()),
                          settings.fixed_control(), settings.fixed_protection())


def job_heaters(job, board_pins: dict[str, tuple[str, str]], program: HeaterProgram) -> tuple[HeaterFirmware, ...]:
    """The heaters a flash image runs: none unless the program sets a heater or the fan, or the machine lists
    `heaters:`; then each of the job's heaters (heater_settings: the board's defaults without `heaters:`) that
    the board has."""
    if not program.first and not program.sets_fan and job.machine.heaters is None:
        return ()
    return tuple(heater_firmware(s, board_pins[name])
                 for name, s in heater_settings(job).items() if name in board_pins)


def stream_heaters(job, board_pins: dict[str, tuple[str, str]]) -> tuple[HeaterFirmware, ...]:
    """The heaters a machine's streaming firmware runs (it plays any job of the machine, so the program does not
    decide): none unless the machine lists `heaters:` or drives an extruder (motor e); then each of its heaters
    that the board has, as job_heaters gives them."""
    if job.machine.heaters is None and "e" not in job.machine.steppers:
        return ()
    return tuple(heater_firmware(s, board_pins[name])
                 for name, s in heater_settings(job).items() if name in board_pins)


def adc_channel(pin) -> int:
    """The ADC input of an analog pin: PF0..PF7 are ADC0..7, PK0..PK7 ADC8..15 (MUX5 in ADCSRB)."""
    if pin.port not in "FK":
        raise BuildError(f"{pin.name} is not an analog input of the ATmega2560 (PF0..PF7, PK0..PK7)")
    return pin.bit + (8 if pin.port == "K" else 0)


def _pwm(pin) -> dict:
    if pin.name not in PWM_CHANNELS:
        raise BuildError(f"{pin.name} has no hardware PWM the heater runtime drives ({', '.join(PWM_CHANNELS)})")
    c = PWM_CHANNELS[pin.name]
    t, ch = c["timer"], c["channel"]
    return {**c, "pin": pin.__dict__, "ocr": f"OCR{t}{ch}", "tccra": f"TCCR{t}A", "com": f"COM{t}{ch}1"}


def _control(h: HeaterFirmware) -> dict:
    c = h.control
    if isinstance(c, FixedPid):
        return {"kind": "pid", "kp_q": c.kp_q, "ki_q": c.ki_q, "kd_q": c.kd_q, "shift": c.shift, "i_max": c.i_max,
                "max_duty": c.max_duty, "hysteresis_dc": 0}
    if isinstance(c, FixedBangBang):
        return {"kind": "bang_bang", "kp_q": 0, "ki_q": 0, "kd_q": 0, "shift": 0, "i_max": 0,
                "max_duty": c.max_duty, "hysteresis_dc": c.hysteresis_dc}
    raise BuildError(f"heater {h.name}: unknown control {c!r}")


def _table_lines(table: tuple[int, ...]) -> list[str]:
    if len(table) != 1024 or not all(-32768 <= int(v) <= 32767 for v in table):
        raise BuildError("a heater's ADC table must hold 1024 int16 deci-degrees")
    return [", ".join(f"{int(v):6d}" for v in table[i:i + TABLE_LINE]) for i in range(0, 1024, TABLE_LINE)]


def heaters_context(config: FirmwareConfig, f_cpu: int, tick_hz: int, stream: bool = False) -> dict:
    """heaters.c.j2's context (and the player's: `heaters`, the hook's SLICE_TICKS; `stream`: the streaming
    firmware's)."""
    if not config.heaters:
        return {"heaters": []}
    heaters, timers, pins_used = [], {}, set()
    for k, h in enumerate(config.heaters):
        pwm, sensor = _pwm(parse_pin(h.pwm_pin)), parse_pin(h.sensor_pin)
        for pin in (pwm["pin"]["name"], sensor.name):
            if pin in pins_used:
                raise BuildError(f"heater {h.name}: pin {pin} is used twice")
            pins_used.add(pin)
        timers.setdefault(pwm["timer"], TIMER_SETUP[pwm["timer"]])
        p = h.protection
        if not (0 <= p.adc_short < p.adc_open <= 1023 and p.min_temp_dc < p.max_temp_dc):
            raise BuildError(f"heater {h.name}: inconsistent limits")
        heaters.append({
            "index": k, "name": h.name, "pwm": pwm, "sensor": sensor.__dict__, "adc": adc_channel(sensor),
            "table": _table_lines(h.table), "control": _control(h), "protection": p,
            "command": HEATER_COMMANDS[h.name], "wait_mask": WAIT_MASKS[h.name]})
    fan_pin = load_target(config.board).get("fan")
    fan = _pwm(parse_pin(fan_pin)) if fan_pin else None
    fan = fan if fan and fan["pin"]["name"] not in pins_used else None
    if fan:
        timers.setdefault(fan["timer"], TIMER_SETUP[fan["timer"]])
    period_ticks = round(PID_PERIOD_S * f_cpu / PERIOD_PRESCALE)
    slice_cycles = STREAM_SLICE_CYCLES if stream else SLICE_CYCLES
    return {"heaters": heaters, "heater_timers": sorted(timers.items()),
            "fan": fan, "rt": RUNTIME_COMMANDS,
            "period_ticks": period_ticks, "period_prescale": PERIOD_PRESCALE,
            "settle_window_dc": SETTLE_WINDOW_DC, "settle_periods": SETTLE_PERIODS,
            "pid_range_dc": PID_FUNCTIONAL_RANGE_DC, "d_filter_shift": D_FILTER_SHIFT, "reasons": REASONS,
            "slice_ticks": math.ceil(slice_cycles * tick_hz / f_cpu),
            "slice_cycles": slice_cycles, "hook_saved": HOOK_SAVED, "fault_bit": HEATERS_FAULT_BIT,
            "busy_bit": HEATERS_BUSY_BIT}
