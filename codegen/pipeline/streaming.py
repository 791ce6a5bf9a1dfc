"""Streaming, from the CLI's side: the machine's firmware (`build --stream`), a job planned for its link
(`plan --stream`), streamed to the simulated firmware (`verify --stream`) or to a board (`stream`).

The streaming firmware belongs to the machine and board, not to a job: it is built from the job file's machine
(a program is optional) and names itself by an identity (codegen/link/protocol.firmware_identity) that the host
checks before it streams. It homes at every START when the machine homes (a delta, or `program.home: true`), runs
the heaters of a printer (codegen/firmware/avr_heaters.stream_heaters), and runs jog mode while it waits for a job
on a machine with `jog:` (the AVR's: templates/avr/jog.c.j2 with `stream`).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from codegen.errors import BuildError
from codegen.firmware.avr.heaters import stream_heaters
from codegen.firmware.config import FirmwareConfig, MotorPins
from codegen.kinematics import make_kinematics
from codegen.link import protocol
from codegen.link.ring import LinkBudget, link_budget
from codegen.motion.jog import jog_plan
from codegen.pipeline.settings import job_settings
from codegen.program.homing import homing_axes
from codegen.tables.hold import HoldPlan, HoldSettings, hold_plan
from codegen.tables.laser import laser_pwm
from codegen.targets import TargetInfo, target_info

STREAM_MODULES = {"avr": "codegen.firmware.avr.stream", "mcs51": "codegen.firmware.mcs51.stream"}
SIM_MODULES = {"avr": "codegen.sim.avr_link", "mcs51": "codegen.sim.mcs51_link"}


@dataclass(frozen=True)
class StreamSetup:
    config: FirmwareConfig
    target: TargetInfo  # with the streaming player's costs
    layout: object  # the firmware module's RingLayout: ring_bytes, where, baud, baud_error_pct
    budget: LinkBudget
    identity: int

    def describe(self) -> str:
        lay = self.layout
        return (f"ring of {lay.ring_bytes} bytes in {lay.where}, link {lay.baud} baud "
                f"({lay.baud_error_pct:+.2f} % from the nominal rate)")


def stream_module(target: str):
    try:
        return importlib.import_module(STREAM_MODULES[target])
    except ModuleNotFoundError as error:
        if error.name != STREAM_MODULES[target]:
            raise
        raise BuildError(f"the {target} target has no streaming firmware yet") from None


def _hold(hold: HoldSettings | None, target) -> HoldPlan | None:
    """The streaming firmware's feed hold (the link's HOLD, RESUME, FEED_DOWN, FEED_UP, and on the AVR the board's
    keys)."""
    if hold is None:
        return None
    return hold_plan(hold, target.tick_hz, target.board, target.board_data, streamed=True)


def stream_setup(job, baud: int | None = None) -> StreamSetup:
    """The machine's streaming firmware config and its link; `baud` overrides machine.link.baud."""
    try:
        target = target_info(job.board, stream=True)
    except FileNotFoundError:
        raise BuildError(f"targets/ has no board '{job.board}'") from None
    kin = make_kinematics(job.machine)
    settings = job_settings(job)
    steppers = job.machine.steppers
    config = FirmwareConfig(
        job_name=job.name, job_file=job.path.name, target=target.target, board=target.board,
        motors=tuple(MotorPins(m, kin.socket(m), bool(steppers[m].invert_dir)) for m in kin.motors),
        step_pulse_us=job.machine.step_pulse_us, dir_setup_us=job.machine.dir_setup_us,
        # A streaming firmware homes at START when the machine homes: a delta, or a job that says so.
        homing=homing_axes(settings.homing, kin, target.tick_hz) if settings.homing.always else (),
        baud=int(baud or job.machine.link.baud or 0),
        heaters=stream_heaters(job, target.heater_pins) if target.target == "avr" else (),
        laser=laser_pwm(settings.laser, job.board, target.board_data, target.f_cpu),
        jog=jog_plan(settings.jog, kin.motors, target.tick_hz) if settings.jog else None,
        hold=_hold(settings.hold, target),
        hold_override=settings.hold.override if settings.hold else 100)
    module = stream_module(target.target)
    layout = module.ring_layout(config)
    budget = link_budget(layout.baud, layout.ring_bytes, len(config.motors),
                         window_updates=getattr(module, "WINDOW_UPDATES", False))  # else the host pings for room
    return StreamSetup(config, target, layout, budget,
                       protocol.firmware_identity(config, target.f_cpu, target.tick_hz))


def build_stream_firmware(setup: StreamSetup, out_dir: Path):
    """Render and build the streaming firmware into out_dir (no image left behind on failure)."""
    module = stream_module(setup.target.target)
    sources = module.render_stream_sources(setup.config)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in ("firmware.hex", "firmware.elf", "report.json"):
        (out_dir / name).unlink(missing_ok=True)
    try:
        return module.build_stream_image(sources, out_dir), sources
    except BuildError as error:
        raise BuildError(f"the streaming firmware for {setup.config.board}: {error}") from None


def stream_chunks(data: bytes, motors: int, size: int = 4096):
    """The table stream as the host sends it: the records, the end marker, the tail padding."""
    for i in range(0, len(data), size):
        yield data[i:i + size]
    yield protocol.tail_padding(motors)


def file_chunks(file: BinaryIO, motors: int, size: int = 1 << 16):
    """stream_chunks of a table stream in a file (host_build's `tables`), read from its start as it goes."""
    file.seek(0)
    while chunk := file.read(size):
        yield chunk
    yield protocol.tail_padding(motors)
