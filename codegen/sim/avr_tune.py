"""`printer-codegen tune --sim`: the tune firmware (codegen/firmware/avr/tune.py) in simavr, its USART0 talking
to the same TuneHost as a real board's port, the heater's thermal plant behind its PWM and thermistor.

The harness runs in link mode (simavr_link.c, in lockstep on simulated time: codegen/sim/avr_link.py) with the
plant file of codegen/sim/avr_plant.py, so the plant, its faults and its trace are the heater runtime's. The
firmware sleeps between control periods and simavr skips the sleep: a tune of several minutes takes seconds.
"""

from __future__ import annotations

import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from codegen.errors import BuildError
from codegen.firmware.avr.board import parse_pin
from codegen.firmware.avr.tune import TuneImage
from codegen.link.tune import TuneHost
from codegen.sim.avr import harness_binary
from codegen.sim.avr_link import BOOT_CYCLES, StreamSim
from codegen.sim.avr_plant import Fault, HeaterPlant, _plant_file

SIM_LIMIT_S = 1800.0  # Marlin's M303 gives up after 20 minutes (MAX_CYCLE_TIME_PID_AUTOTUNE); a little more here
OFF_S = 5.0  # simulated time for OFF and its answer after the limit


@dataclass(frozen=True)
class PlantLog:
    """What the plant's trace says (simavr_plant.c): its temperature every 0.1 s, the firmware's readings, the
    heater's duty at each change."""

    time_s: np.ndarray
    temp_c: np.ndarray
    adc: np.ndarray  # the firmware's thermistor readings, one per control period
    duty_s: np.ndarray  # when the duty changed
    duty: np.ndarray  # to what (0..1)


@dataclass
class TuneRun:
    """A simulated tune: the host's session and the plant's log."""

    host: TuneHost
    seconds: float  # simulated
    plant: PlantLog


class TuneSim(StreamSim):
    """The harness in link mode with a plant: StreamSim's exchange with the firmware, for an image without a
    ring (no ring symbols, no homing, no step pins to decode); `drive` instead of its `session`."""

    def __init__(self, hex_path: Path, image: TuneImage, plant: HeaterPlant, faults: tuple[Fault, ...] = ()):
        self.f_cpu = image.f_cpu
        self._tmp = tempfile.TemporaryDirectory(prefix="printer-codegen-tune-")
        work = Path(self._tmp.name)
        self.log = work / "plant.txt"
        spec = work / "plant-spec.txt"
        spec.write_text(_plant_file(image.config, {image.heater.name: plant}, faults, self.f_cpu, self.log, None))
        self._stderr = open(work / "stderr.txt", "w+b")
        pwm = parse_pin(image.config.heaters[0].pwm_pin)
        byte_cycles = round(10 * self.f_cpu / image.baud)
        cmd = [str(harness_binary()), image.mcu, str(self.f_cpu), str(hex_path), str(work / "edges.bin"),
               str(BOOT_CYCLES), f"link={byte_cycles}", f"plant={spec}", f"{pwm.port}{pwm.bit}"]
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr)
        self.last = self._read()
        if self.last.state != "running":
            raise BuildError(f"the tune firmware {self.last.state} at boot ({hex_path})")

    def drive(self, host, limit_s: float) -> bool:
        """Run `host` (TuneHost's interface: transmit, receive, wake_at, done) until it is done; False if
        `limit_s` simulated seconds passed first."""
        answer = self.last
        end = answer.cycle + round(limit_s * self.f_cpu)
        while not host.done and answer.cycle < end:
            now = answer.cycle / self.f_cpu
            data = host.transmit(now)
            answer = self.exchange(data, self._wake_cycle(host.wake_at(), now, answer.cycle), end)
            if answer.data:
                host.receive(answer.data, int(answer.arrived[-1]) / self.f_cpu)
            if answer.state != "running":
                raise BuildError(f"the tune firmware {answer.state} in simavr after {answer.cycle} cycles")
        return host.done

    def plant_log(self) -> PlantLog:
        """After close(): the plant's trace."""
        lines = [line.split() for line in self.log.read_text().splitlines()]
        samples = np.array([[float(r[1]), float(r[3])] for r in lines if r[0] == "S"]).reshape(-1, 2)
        changes = np.array([[float(r[1]), float(r[3])] for r in lines if r[0] == "D"]).reshape(-1, 2)
        adc = np.array([int(r[3]) for r in lines if r[0] == "A"], dtype=np.int64)
        return PlantLog(samples[:, 0] / self.f_cpu, samples[:, 1], adc, changes[:, 0] / self.f_cpu,
                        changes[:, 1] / 256)

    def close(self) -> None:  # the plant's log stays until the temporary folder goes (cleanup)
        if self._proc.poll() is None:
            self._proc.stdin.close()
            self._proc.wait()
        self._stderr.close()

    def cleanup(self) -> None:
        self._tmp.cleanup()


def simulate_tune(hex_path: Path, image: TuneImage, host: TuneHost, plant: HeaterPlant,
                  faults: tuple[Fault, ...] = (), limit_s: float = SIM_LIMIT_S) -> TuneRun:
    """Run `host` against the tune image in simavr with `plant` behind the heater, to the session's end or
    `limit_s` simulated seconds (then the host turns the heater off and the run ends)."""
    sim = TuneSim(hex_path, image, plant, faults)
    try:
        if not sim.drive(host, limit_s):
            host.stop(sim.last.cycle / sim.f_cpu, "failed")
            sim.drive(host, OFF_S)
            host.outcome, host.error = "failed", f"no {host.cycles} relay cycles within {limit_s:g} s"
        sim.close()
        return TuneRun(host, sim.last.cycle / sim.f_cpu, sim.plant_log())
    finally:
        sim.close()
        sim.cleanup()
