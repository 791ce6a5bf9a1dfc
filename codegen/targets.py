"""Board and MCU data from targets/*.yaml, and what the host needs to know about the player on each MCU."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import yaml

from codegen.paths import targets_dir


@dataclass(frozen=True)
class TargetInfo:
    board: str
    mcu: str
    target: str
    f_cpu: int
    tick_hz: int  # the player's timer tick
    flash_bytes: int
    ram_bytes: int
    board_data: dict
    mcu_data: dict

    def _cycles(self, us: float) -> int:
        return int(np.ceil(us * self.f_cpu / 1e6))

    def _pad(self, step_pulse_us: float) -> int:
        """Cycles the interrupt waits to hold STEP high longer than its own code does."""
        return max(0, self._cycles(step_pulse_us) - int(self.mcu_data["step_high_min_cycles"]))

    def run_gap_ticks(self, motors: int, step_pulse_us: float = 2.0) -> int:
        """The closest two events may be when the second starts a new rate run, for this many motors
        (measured for 1, 3 and 5 motors; linear in between)."""
        known = sorted((int(k.split("_")[3]), v) for k, v in self.mcu_data.items()
                       if k.startswith("run_event_cycles_"))
        cycles = np.interp(motors, [m for m, _ in known], [c for _, c in known]) + self._pad(step_pulse_us)
        return int(np.ceil(cycles * self.tick_hz / self.f_cpu))

    def block_gap_ticks(self, step_pulse_us: float = 2.0, dir_setup_us: float = 1.0) -> int:
        """The closest two events may be when the second starts a block: the worst-case block load, and the
        new DIR levels must stand `dir_setup_us` before the block's first STEP edge."""
        # The next block's first STEP edge may come as early as the shortest latency after its tick.
        shortest = self.mcu_data.get("isr_latency_min_cycles", self.mcu_data["isr_latency_cycles"])
        dir_ready = int(self.mcu_data["block_dir_write_cycles"]) - int(shortest) + self._cycles(dir_setup_us)
        cycles = max(int(self.mcu_data["min_event_cycles"]), dir_ready) + self._pad(step_pulse_us)
        return int(np.ceil(cycles * self.tick_hz / self.f_cpu))

    def max_event_rate(self, motors: int, step_pulse_us: float = 2.0) -> float:
        """Events per second the planner may ask for: a fifth below what the player sustains with a new
        run at every event, so that pushing events apart stays the exception."""
        return self.tick_hz / (1.25 * self.run_gap_ticks(motors, step_pulse_us))

    def block_overhead_s(self, motors: int, step_pulse_us: float = 2.0, dir_setup_us: float = 1.0) -> float:
        """How much longer than an ordinary event a block's first event takes the player, with the same
        headroom as `max_event_rate`: the planner gives every block at least this much more time."""
        extra = self.block_gap_ticks(step_pulse_us, dir_setup_us) - self.run_gap_ticks(motors, step_pulse_us)
        return 1.25 * max(extra, 0) / self.tick_hz

    def block_load_s(self, step_pulse_us: float = 2.0, dir_setup_us: float = 1.0) -> float:
        """The least time between a block's first event and the one before, with `max_event_rate`'s headroom
        (the compressor pushes that event 1.1 x the gap + 2 ticks after the one before)."""
        return 1.25 * self.block_gap_ticks(step_pulse_us, dir_setup_us) / self.tick_hz

    def pulse_jitter_s(self, heaters: bool = False) -> float:
        """How much earlier than its tick + the constant latency a pulse may come against the one before: the
        latency's spread (a link interrupt in the way, a hold poll), then main's longest stretch with interrupts
        off (a heater stage's check where heaters run, heater_check_cycles; the link's answers, main_cli_cycles),
        and the measurements' +-2 cycles. Eight steps may be this much closer than planned."""
        latency = int(self.mcu_data.get("isr_latency_cycles", 0))
        spread = latency - int(self.mcu_data.get("isr_latency_min_cycles", latency))
        hook = int(self.mcu_data.get("heater_check_cycles", 0)) if heaters else 0
        return (spread + max(hook, int(self.mcu_data.get("main_cli_cycles", 0))) + 4) / self.f_cpu

    @property
    def isr_latency_us(self) -> float:
        """From the timer event to the first STEP edge: the player's constant delay."""
        return int(self.mcu_data.get("isr_latency_cycles", 0)) * 1e6 / self.f_cpu

    @property
    def heater_pins(self) -> dict[str, tuple[str, str]]:
        return board_heater_pins(self.board)

    @property
    def max_gap_s(self) -> float:
        """Longest wait between two events the player's 24.8 fixed-point interval can express."""
        return ((1 << 24) - 1) / self.tick_hz


@lru_cache(maxsize=None)
def _load(name: str) -> dict:
    return yaml.safe_load((targets_dir() / f"{name}.yaml").read_text(encoding="utf-8"))


def board_heater_pins(board: str) -> dict[str, tuple[str, str]]:
    """The board file's `heaters: {hotend: {pwm: PB4, sensor: PK5}, ...}`: each heater's MOSFET (PWM) pin and its
    thermistor's analog input; {} for a board without heater outputs (the 8051 boards)."""
    heaters = _load(board).get("heaters") or {}
    return {str(name): (str(spec["pwm"]), str(spec["sensor"])) for name, spec in heaters.items()}


def target_info(board: str, stream: bool = False, laser: bool = False, hold: bool = False) -> TargetInfo:
    """`stream`: the costs of the streaming player (records from the link's ring buffer, the link's interrupts
    beside it), where the MCU's or board's file has them (`stream_player_costs`). `laser`: a player with a PWM
    laser, whose every event may read a power record and write the PWM (laser_record_cycles more). `hold`: a
    player with feed hold, whose every event may take the dilated path and main's key poll (hold_cycles more;
    with a laser, its power follows the feed factor: laser_hold_cycles more)."""
    board_data = _load(board)
    mcu = board_data["mcu"]
    # A board may carry its own measured player costs (a display makes the interrupt save main's registers).
    mcu_data = {**_load(mcu), **(board_data.get("player_costs") or {})}
    if stream:
        mcu_data.update(_load(mcu).get("stream_player_costs") or {})
        mcu_data.update(board_data.get("stream_player_costs") or {})
    extra = (int(mcu_data.get("laser_record_cycles", 0)) * laser + int(mcu_data.get("hold_cycles", 0)) * hold
             + int(mcu_data.get("laser_hold_cycles", 0)) * (laser and hold))
    if hold and stream:  # main's poll, interrupts off, may come after a link interrupt: in a pulse's way
        mcu_data["isr_latency_cycles"] = int(mcu_data["isr_latency_cycles"]) + int(mcu_data.get("hold_poll_cycles", 0))
    if extra:
        grows = ("min_event_cycles", "block_dir_write_cycles")
        mcu_data.update({k: v + extra for k, v in mcu_data.items()
                         if k in grows or k.startswith(("run_event_cycles_", "block_event_cycles_"))})
    f_cpu = int(mcu_data["f_cpu"])
    tick_hz = int(mcu_data.get("tick_hz", f_cpu))
    return TargetInfo(
        board=board,
        mcu=mcu,
        target=board_data["target"],
        f_cpu=f_cpu,
        tick_hz=tick_hz,
        flash_bytes=int(mcu_data["flash"]),
        ram_bytes=int(mcu_data["ram"]),
        board_data=board_data,
        mcu_data=mcu_data,
    )
