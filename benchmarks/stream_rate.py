"""How fast the streaming ATmega2560 player steps with its link busy, and what the link costs, in simavr.

The schedules are firmware_rate.py's (beside this script: a lead event, then events a constant interval apart;
modes run, runs, block, long_block), played by the streaming image (codegen/firmware/avr/stream.py) on a RAMPS
1.4 (x, y, z, e): the host (codegen/link/host.py, DATA frames of the link budget's payload) sends the schedule
before START, then goes on sending stream bytes after its end (stored in the ring, never played) back to back at
250000 baud while the player plays: every receive and transmit interrupt of a busy link comes between the events.
For each case, the shortest interval (in whole ticks: a link interrupt in front of a step interrupt can push its
compare write past the match, which a build counting CPU cycles would hide) at which every pulse still comes no
later than its tick + LATE_LIMIT cycles (the player keeps up; one link interrupt may delay a pulse), no received
byte comes late for the USART and the ring never runs dry. Also: the link's interrupts (the longest, cycles per
received byte, the share of the CPU at the line's full rate), the latency with the link busy, the DIR write of a
block load, the STEP high time, and homing with the link busy (the shortest shared homing step interval at which
each step comes an interval after the one before within the link's interrupt). With --write the figures go into
targets/atmega2560.yaml's stream_player_costs.

    python benchmarks/stream_rate.py [--write]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from functools import lru_cache
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from firmware_rate import (F_CPU, MARGIN_CYCLES, MCU, MOTOR_COUNTS, PAD_MARGIN, config, homing_config,  # noqa: E402
                           latencies, prescaler, schedule, suffix)
from shortest import shortest  # noqa: E402 - beside this script

import codegen.tables.format as tables  # noqa: E402
from codegen.errors import BuildError  # noqa: E402
from codegen.firmware.avr.stream import build_stream_image, render_stream_sources, ring_layout  # noqa: E402
from codegen.firmware.config import load_target  # noqa: E402
from codegen.link import protocol  # noqa: E402
from codegen.link.host import HostLink  # noqa: E402
from codegen.link.ring import link_budget  # noqa: E402
from codegen.paths import targets_dir  # noqa: E402
from codegen.sim.avr_link import StreamSim  # noqa: E402

LATE_LIMIT = 120  # cycles from a pulse's tick: the idle latency and one link interrupt, with room
TOLERANCE = 2  # cycles: homing steps around their interval, beyond the link's delay
RESPONSE_CYCLES = 5 + 5  # a real part's interrupt response and RETI (3-byte PC), which simavr does not count
JUNK_BYTES = 60_000  # sent after the schedule: the link stays busy while it plays
HOMING_SWITCHES = 40  # steps to the first motor's switch (10 more for each next one)
HOMING_BACKOFF = 20
PLANNER_HEADROOM = 1.25  # codegen/targets.py max_event_rate: a fifth below what the player sustains


@lru_cache(maxsize=None)
def image(n_motors: int, tick_hz: int, homing_interval: int, workdir: Path):
    """The streaming image for n motors (homing them at `homing_interval` ticks, 0: none), built once."""
    cfg = homing_config(n_motors, homing_interval) if homing_interval else config(n_motors)
    mcu = load_target(MCU)
    limit, mcu["homing_event_cycles"] = mcu["homing_event_cycles"], [0] * 5  # measure below the checked minimum
    try:
        sources = render_stream_sources(cfg)
    finally:
        mcu["homing_event_cycles"] = limit
    out = workdir / f"stream-{n_motors}-{tick_hz}-{homing_interval}"
    return cfg, build_stream_image(sources, out), protocol.firmware_identity(cfg, F_CPU, tick_hz)


def busy_play(n_motors: int, interval: int, events: int, mode: str, workdir: Path, tick_hz: int,
              homing_interval: int = 0):
    """Play firmware_rate.py's schedule with the link busy: (schedule, trace, link figures, harness answer)."""
    sched = schedule(n_motors, interval, events, mode, tick_hz)
    cfg, img, identity = image(n_motors, tick_hz, homing_interval, workdir)
    data = tables.encode(sched).data + protocol.tail_padding(n_motors)
    layout = ring_layout(cfg)
    budget = link_budget(layout.baud, layout.ring_bytes, n_motors)
    host = HostLink([data, bytes(JUNK_BYTES)], n_motors, identity, 10 / layout.baud, len(data),
                    payload=budget.payload)
    switches = {m: HOMING_SWITCHES + 10 * m for m in range(n_motors)} if homing_interval else None
    cycles = int(sched.run_count.sum()) * interval * (F_CPU // tick_hz) + 4_000_000
    with StreamSim(img.hex_path, cfg, switches) as sim:
        trace, figures = sim.session(host, 2 * cycles)
        answer = sim.last
    if host.outcome != "finished":
        raise BuildError(f"{n_motors} motor(s), mode {mode}: the stream ended {host.outcome}")
    return sched, trace, figures, answer


def on_time(n_motors: int, interval: int, events: int, mode: str, workdir: Path, tick_hz: int) -> bool:
    try:
        sched, trace, figures, _ = busy_play(n_motors, interval, events, mode, workdir, tick_hz)
    except BuildError:
        return False
    late = latencies(sched, trace, tick_hz)
    return (late is not None and figures.lost_bytes == 0 and figures.underruns == 0
            and all(m.min() >= 0 and m.max() <= LATE_LIMIT for m in late))


def fastest(n_motors: int, events: int, mode: str, workdir: Path, lo: int = 2, hi: int = 500) -> int:
    """The shortest interval that plays on time with the link busy, in CPU cycles: whole ticks (a link interrupt
    before a step interrupt can push its compare write past the match, which a build counting CPU cycles hides)."""
    tick_hz = load_target(MCU)["tick_hz"]
    ticks = shortest(lambda t: on_time(n_motors, t, events, mode, workdir, tick_hz), lo, hi,
                     f"{n_motors} motor(s), mode {mode}, link busy")
    return ticks * (F_CPU // tick_hz)


def homing_on_time(n_motors: int, interval: int, workdir: Path, tick_hz: int, jitter: int) -> bool:
    """Home n motors at `interval` ticks per step with the link busy: each step an interval after the one before
    within the link's delay (`jitter` cycles), the counts right, DIR set up 1 us before."""
    try:
        _, trace, figures, _ = busy_play(n_motors, 2000, 1, "run", workdir, tick_hz, homing_interval=interval)
    except BuildError:
        return False
    if figures.lost_bytes or any(s is None or s < F_CPU // 1_000_000 for s in trace.dir_setup_min_cycles):
        return False
    scale = F_CPU // tick_hz
    for m in range(n_motors):
        home = (trace.step_motor == m) & (trace.step_phase == "home")
        cycles, dirs = trace.step_cycle[home], trace.step_dir[home]
        if len(cycles) != HOMING_SWITCHES + 10 * m + 2 * HOMING_BACKOFF:
            return False
        same_phase = dirs[1:] == dirs[:-1]
        if np.abs(np.diff(cycles)[same_phase] - interval * scale).max() > jitter + TOLERANCE + 1:
            return False
    return True


def link_figures(work: Path) -> dict:
    """The link's interrupts with the link busy (4 motors, a run load at every event, 2000 cycles apart)."""
    tick_hz = load_target(MCU)["tick_hz"]
    sched, trace, figures, answer = busy_play(4, 250, 300, "runs", work, tick_hz)
    rx_max, tx_max = (m + RESPONSE_CYCLES for m in answer.isr_max)
    rx, tx = (total + RESPONSE_CYCLES * count for total, count in zip(answer.isr_cycles, answer.isr_count))
    late = latencies(sched, trace, tick_hz)
    return {"link_isr_cycles": max(rx_max, tx_max), "rx_isr_max": rx_max, "tx_isr_max": tx_max,
            "rx_cycles_per_byte": rx / answer.rx_bytes, "link_cycles_per_byte": (rx + tx) / answer.rx_bytes,
            "latency_busy": (min(int(m.min()) for m in late), max(int(m.max()) for m in late)),
            "stack_low": answer.sp_min}


def measure(work: Path) -> dict:
    out = link_figures(work)
    for n in MOTOR_COUNTS:
        out[f"event_cycles_{suffix(n)}"] = fastest(n, 2000, "run", work)
        out[f"run_event_cycles_{suffix(n)}"] = fastest(n, 1000, "runs", work)
        short, long = fastest(n, 400, "block", work), fastest(n, 2048, "long_block", work)  # each fits the ring
        out[f"short_block_cycles_{suffix(n)}"], out[f"long_block_cycles_{suffix(n)}"] = short, long
        out[f"block_event_cycles_{suffix(n)}"] = max(short, long)
    tick_hz = load_target(MCU)["tick_hz"]
    scale = F_CPU // tick_hz
    worst = max(out[f"block_event_cycles_{suffix(n)}"] for n in MOTOR_COUNTS)
    dir_write, highs, lates = 0, [], [out["latency_busy"][1]]
    for n in MOTOR_COUNTS:
        for mode, key in (("run", "event"), ("runs", "run_event"), ("block", "short_block"),
                          ("long_block", "long_block")):
            # With the planner's headroom (a fifth: codegen/targets.py), and at the worst block load's pace.
            for ticks in (-(-PLANNER_HEADROOM * out[f"{key}_cycles_{suffix(n)}"] // scale), -(-worst // scale)):
                sched, trace, _, _ = busy_play(n, int(ticks), 300, mode, work, tick_hz)  # it fits the ring
                late = latencies(sched, trace, tick_hz)
                highs += [h for h in trace.pulse_high_min_cycles if h is not None]
                lates += [int(m.max()) for m in late]
            if mode in ("block", "long_block") and n == MOTOR_COUNTS[-1]:
                # DIR changes right after the previous event's pulses: compare match to the last DIR write.
                dir_write = max(dir_write, max(int(ticks) * scale + int(m.max()) - s
                                               for m, s in zip(late, trace.dir_setup_min_cycles)))
    # A pulse may wait for one whole link interrupt: the latency is no longer constant; its bound is what counts.
    out["isr_latency_cycles"] = max(max(lates), out["latency_busy"][0] + out["link_isr_cycles"])
    out["step_high_time_cycles"] = min(highs)
    out["step_high_min_cycles"] = min(highs) - PAD_MARGIN
    out["block_dir_write_cycles"] = dir_write
    out["min_event_cycles"] = worst + MARGIN_CYCLES
    pulse = int(np.ceil(2.0 * F_CPU / 1e6))
    with prescaler(1) as hz:
        out["homing_event_cycles"] = [
            shortest(lambda c: homing_on_time(k, c, work, hz, out["link_isr_cycles"]), 10, 6000,
                     f"homing {k} motor(s), link busy") - pulse + MARGIN_CYCLES for k in range(1, 5)]
    return out


STREAM_KEYS = ("min_event_cycles", "isr_latency_cycles", *(f"{kind}_cycles_{suffix(n)}" for n in MOTOR_COUNTS
               for kind in ("event", "run_event", "block_event")), "block_dir_write_cycles", "step_high_min_cycles",
               "homing_event_cycles", "link_isr_cycles")


def write_target(figures: dict) -> None:
    """Replace the stream_player_costs mapping at the end of targets/atmega2560.yaml."""
    path = targets_dir() / f"{MCU}.yaml"
    text = path.read_text(encoding="utf-8")
    head, found, _ = text.partition("\nstream_player_costs:")
    if not found:
        raise SystemExit(f"{path}: has no `stream_player_costs:` mapping to replace")
    lines = [f"  {key}: {figures[key]}".replace("'", "") for key in STREAM_KEYS]
    path.write_text(head + "\nstream_player_costs:\n" + "\n".join(lines) + "\n", encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help="write the figures into targets/atmega2560.yaml")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="stream-rate-") as tmp:
        figures = measure(Path(tmp))
    flash = load_target(MCU)
    byte_s = 10 / 250_000
    share = figures["link_cycles_per_byte"] / (byte_s * F_CPU)
    print(f"Streaming ATmega2560 player at {F_CPU / 1e6:g} MHz in simavr, the link busy at 250000 baud")
    print(f"  link interrupts: the longest {figures['link_isr_cycles']} cycles (receive {figures['rx_isr_max']}, "
          f"transmit {figures['tx_isr_max']}; a real part's response and RETI included)")
    print(f"  {figures['rx_cycles_per_byte']:.1f} cycles per received byte in the receive interrupt, "
          f"{figures['link_cycles_per_byte']:.1f} with the transmit interrupt's ACKs: {100 * share:.1f} % of the CPU")
    print(f"  latency with the link busy: {figures['latency_busy'][0]}..{figures['latency_busy'][1]} cycles; "
          f"the lowest stack pointer 0x{figures['stack_low']:04X}")
    for n in MOTOR_COUNTS:
        for kind, what in (("event", "sustained"), ("run_event", "a run load at every event"),
                           ("short_block", "a short block (and run) load at every event"),
                           ("long_block", "a long block and long run load (every 256 events)")):
            cycles = figures[f"{kind}_cycles_{suffix(n)}"]
            key = f"{kind}_cycles_{suffix(n)}"
            was = flash.get(key)
            cost = f" (flash image {was}: {100 * (cycles / was - 1):+.0f} %)" if was else ""
            print(f"  {n} motor(s), {what}: {cycles} cycles per event, {F_CPU / cycles:,.0f} events/s{cost}")
    for key in ("isr_latency_cycles", "step_high_time_cycles", "step_high_min_cycles", "block_dir_write_cycles",
                "min_event_cycles", "homing_event_cycles"):
        print(f"  {key}: {figures[key]} (flash image: {flash.get(key, '-')})")
    if args.write:
        write_target(figures)
        print(f"written into targets/{MCU}.yaml")


if __name__ == "__main__":
    main()
