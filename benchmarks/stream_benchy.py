"""Benchmark: `verify --stream` of the whole PrusaSlicer Benchy for a Prusa MINI (examples/printers/benchy-mini.yaml)
on a RAMPS board: the print streamed by the host's own protocol code (codegen/link/) into simavr's USART at 250000
baud, every pulse compared with the twin's.

    python benchmarks/stream_benchy.py [--job JOB.yaml]

`printer-codegen verify JOB --stream --json` runs in this process (after the imports); the simulator's own wall
time (codegen/link/host.py LinkFigures.wall_s) is taken from its call. Printed: the planned and the simulated
duration, the wall time of the whole verb and of the simulation, the simulator's speed against real time
(simulated s / wall s), what went over the line (bytes, frames, the line's busy share, retransmits, underruns,
lost bytes), the ring's lowest fill (simulated and planned) and its prefill, and the time the link cost: the
plan's slowdown for it (link_slowdown_s) and the simulated minus the planned duration (which a flashed image
shows too, up to the run fitter's window at each end: codegen/tables/compress.py TimingWindow). The Benchy's printer runs
its heaters: the holds at its M190 / M109 and each heater's figures are printed too (the simulated duration counts
from the first step, after the heat-up).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from codegen.cli.main import main as cli_main  # noqa: E402
from codegen.pipeline.streaming import SIM_MODULES  # noqa: E402
from codegen.tables.compress import TimingWindow  # noqa: E402

JOB = Path(__file__).resolve().parent.parent / "examples" / "printers" / "benchy-mini.yaml"


@contextlib.contextmanager
def simulator_figures():
    """Collect the LinkFigures of every simulated stream (simulate_stream, and simulate_stream_heaters for a
    firmware with heaters: both give them second) made inside the block."""
    collected = []
    patched = []
    for module in (importlib.import_module(name) for name in SIM_MODULES.values()):
        for name in ("simulate_stream", "simulate_stream_heaters"):
            if hasattr(module, name):
                patched.append((module, name, getattr(module, name)))

    def recording(original):
        def simulate(*args, **kwargs):
            out = original(*args, **kwargs)
            collected.append(out[1])
            return out
        return simulate

    for module, name, original in patched:
        setattr(module, name, recording(original))
    try:
        yield collected
    finally:
        for module, name, original in patched:
            setattr(module, name, original)


def verify_streamed(job: Path, out: Path) -> tuple[dict, float, float]:
    """(verify --stream --json's result, the verb's wall s, the simulation's wall s)."""
    stdout = io.StringIO()
    with simulator_figures() as figures, contextlib.redirect_stdout(stdout):
        began = time.perf_counter()
        code = cli_main(["verify", str(job), "--stream", "--json", "--out", str(out)])
        wall = time.perf_counter() - began
    if not stdout.getvalue():
        raise SystemExit(f"verify --stream {job} gave no result (exit code {code})")
    return json.loads(stdout.getvalue()), wall, figures[0].wall_s


def clock(seconds: float) -> str:
    minutes, s = divmod(seconds, 60)
    return f"{int(minutes) // 60}:{int(minutes) % 60:02d}:{s:06.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--job", type=Path, default=JOB)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="stream-benchy-") as tmp:
        result, wall, sim_wall = verify_streamed(args.job, Path(tmp))
        ring_bytes = json.loads((Path(tmp) / "report.json").read_text())["link"]["ring_bytes"]
    link = result["link"]
    simulated, planned = result["duration_s"], result["planned_duration_s"]
    steps = sum(m["steps"] for m in result["motors"].values())
    timing = max(m["max_timing_error_us"] for m in result["motors"].values())
    busy = link["bytes"] * 10 / link["baud"] / simulated  # 10 bit times a byte: start, 8 data, stop
    print(f"verify --stream {args.job.name}: {'PASS' if result['pass'] else 'FAIL'} on {result['board']} "
          f"({result['target']}), {steps:,} steps, every pulse within {timing} us of the twin")
    for problem in result["problems"]:
        print(f"  problem: {problem}")
    print(f"  planned duration    {planned:12.6f} s  ({clock(planned)})")
    print(f"  simulated duration  {simulated:12.6f} s  ({clock(simulated)})")
    print(f"  wall time           {wall:12.3f} s  (the whole verb: firmware build, plan, twin, simulation, checks)")
    print(f"  simulation          {sim_wall:12.3f} s  of wall time: {simulated / sim_wall:.1f} x real time "
          f"({simulated / wall:.1f} x over the whole verb)")
    print(f"  line at {link['baud']} baud: {link['bytes']:,} bytes in {link['frames']:,} frames, busy "
          f"{100 * busy:.1f} % of the print; {link['retransmits']} retransmits, {link['underruns']} underruns, "
          f"{link['lost_bytes']} lost bytes")
    print(f"  ring of {ring_bytes} bytes: prefill {link['prefill_bytes']} bytes, lowest fill "
          f"{link['min_ring_fill_bytes']} bytes simulated, {link['planned_min_ring_fill_bytes']} planned")
    for hold in result.get("holds", []):
        print(f"  hold at {hold['at_s']:.2f} s simulated for {hold['waited_s']:.2f} s: waited for "
              f"{', '.join(hold['heaters'])}")
    for name, h in result.get("heaters", {}).items():
        print(f"  heater {name}: last target {h['target_c']:g} degC, overshoot {h['overshoot_c']} degC, band "
              f"{h['band_c']} degC, trip {h['trip']}")
    print(f"  time lost to the link: {link['link_slowdown_s']:.6f} s planned (link_slowdown_s); simulated minus "
          f"planned {1e6 * (simulated - planned):+.0f} us (a flashed image's first and last steps may stand "
          f"{TimingWindow().max_us:g} us from the plan's too: the run fitter's window)")


if __name__ == "__main__":
    main()
