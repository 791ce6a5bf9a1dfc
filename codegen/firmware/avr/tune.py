"""The tune firmware for an ATmega2560 board (templates/avr/tune.c.j2): Marlin's M303 relay on one heater, its
reports and the host's answers over USART0 (codegen/link/tune.py), with the heater runtime's thermal protection.

The image holds tune.c, the heater's thermistor table (heaters_table.c.j2) and heaters.h.j2 (the table's
declaration); pins, PWM timer, ADC channel, period and protection come from the heater runtime's context
(codegen/firmware/avr/heaters.py), so both images drive the heater the same way. The other heaters' MOSFETs and
the fan are held low and every stepper driver disabled. Built like the player's image, with the same check that
no division or float routine is linked.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

from codegen.errors import BuildError
from codegen.firmware.avr.board import parse_pin
from codegen.firmware.avr.heaters import heater_firmware, heaters_context
from codegen.firmware.avr.toolchain import CFLAGS, check_integer_only, run_avr
from codegen.firmware.config import FirmwareConfig, load_target
from codegen.firmware.render import render
from codegen.heaters.control import PID_PERIOD_S
from codegen.heaters.tuning import RELAY_MIN_DWELL_S
from codegen.link.tune import FRAME_TYPES, HEATER_NAMES
from codegen.program.heater_settings import HeaterSettings, heater_settings
from codegen.targets import board_heater_pins

TUNE_BAUD = 250_000  # exact at 16 MHz with U2X (UBRR 7), the streaming firmware's default too
TEMP_EVERY_PERIODS = 10  # a TEMP frame every second
MAX_BAUD_ERROR = 0.02


@dataclass(frozen=True)
class TuneImage:
    heater: HeaterSettings
    config: FirmwareConfig  # the board and this one heater (codegen.sim.avr_tune runs the plant behind it)
    mcu: str
    f_cpu: int
    baud: int


def tune_setup(job, heater: str) -> TuneImage:
    """The tune image's settings for `heater` of the job (its `heaters:` or the board's defaults)."""
    settings = heater_settings(job)
    pins = board_heater_pins(job.board)
    if heater not in settings or heater not in pins:
        have = sorted(set(settings) & set(pins))
        raise BuildError(f"no heater `{heater}` on board {job.board} in this job "
                         f"(tunable: {', '.join(have) or 'none'})")
    config = FirmwareConfig(job_name=job.name, job_file=job.path.name, target="avr",
                            board=job.board, motors=(), heaters=(heater_firmware(settings[heater],
                                                                                          pins[heater]),))
    mcu = load_target(load_target(job.board)["mcu"])
    return TuneImage(settings[heater], config, mcu["name"], int(mcu["f_cpu"]), TUNE_BAUD)


def _off_pins(config: FirmwareConfig, tuned: str) -> list[dict]:
    """Outputs held at their safe level: the other heaters' MOSFETs and the fan low, the drivers disabled."""
    board = load_target(config.board)
    pins = [{**parse_pin(pwm).__dict__, "what": f"{name}'s MOSFET", "level": 0}
            for name, (pwm, _sensor) in board_heater_pins(config.board).items() if name != tuned]
    if board.get("fan"):
        pins.append({**parse_pin(board["fan"]).__dict__, "what": "the fan", "level": 0})
    off = int(bool(board["enable_active_low"]))
    for socket, spec in sorted(board["steppers"].items()):
        pins.append({**parse_pin(spec["enable"]).__dict__, "what": f"driver {socket} disabled", "level": off})
    mine = {h.pwm_pin for h in config.heaters}
    return [p for p in pins if p["name"] not in mine]


def render_tune_sources(image: TuneImage) -> dict[str, str]:
    """tune.c, heaters.h and heaters_table.c for the image's heater."""
    config = image.config
    context = heaters_context(config, image.f_cpu, image.f_cpu)
    ubrr = round(image.f_cpu / (8 * image.baud)) - 1
    if abs(image.f_cpu / (8 * (ubrr + 1)) / image.baud - 1) > MAX_BAUD_ERROR:
        raise BuildError(f"{image.baud} baud is not within {MAX_BAUD_ERROR:.0%} at {image.f_cpu} Hz")
    name = config.heaters[0].name
    context.update({
        "job_file": config.job_file, "target": config.target, "mcu": image.mcu,
        "h": context["heaters"][0], "p": context["heaters"][0]["protection"],
        "heater_index": HEATER_NAMES.index(name), "frame_types": sorted(FRAME_TYPES.items(), key=lambda kv: kv[1]),
        "dwell_periods": round(RELAY_MIN_DWELL_S / PID_PERIOD_S), "temp_every": TEMP_EVERY_PERIODS,
        "baud": image.baud, "ubrr": ubrr, "off_pins": _off_pins(config, name), "stream": False,
    })
    return {"tune.c": render("avr/tune.c.j2", **context), "heaters.h": render("avr/heaters.h.j2", **context),
            "heaters_table.c": render("avr/heaters_table.c.j2", **context)}


def build_tune_image(image: TuneImage, out_dir: Path) -> Path:
    """Write the sources into out_dir and build firmware.elf and firmware.hex (the hex last: no partial image)."""
    sources = render_tune_sources(image)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    hex_path, elf_path = out_dir / "firmware.hex", out_dir / "firmware.elf"
    for stale in (hex_path, elf_path):
        stale.unlink(missing_ok=True)
    arch = [f"-mmcu={image.mcu}", f"-DF_CPU={image.f_cpu}UL"]
    with tempfile.TemporaryDirectory(prefix=".build-", dir=out_dir) as tmp:
        work = Path(tmp)
        for name, text in sorted(sources.items()):
            (out_dir / name).write_text(text, encoding="utf-8")
            (work / name).write_text(text, encoding="utf-8")
        objects = [name[:-2] + ".o" for name in sorted(sources) if name.endswith(".c")]
        for obj in objects:
            run_avr(["avr-gcc", *arch, *CFLAGS, "-c", obj[:-2] + ".c", "-o", obj], work, f"avr-gcc on {obj[:-2]}.c")
        run_avr(["avr-gcc", *arch, "-o", "firmware.elf", *objects], work, "linking the tune firmware")
        check_integer_only(work / "firmware.elf", work)
        run_avr(["avr-objcopy", "-O", "ihex", "-R", ".eeprom", "firmware.elf", "firmware.hex"], work, "avr-objcopy")
        (work / "firmware.elf").replace(elf_path)
        (work / "firmware.hex").replace(hex_path)
    return hex_path
