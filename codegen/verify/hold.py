"""`verify --hold SECONDS` and `verify --override PERCENT` on an image with machine.feed_hold: the simulator
presses the board's hold keys (an ATmega2560's or an 8051's flash image) or the host sends HOLD, RESUME, FEED_DOWN
and FEED_UP frames (a streaming firmware: codegen/verify/hold_runs.py), and every pulse is compared with the twin on the
dilated clock that codegen/tables/hold.py models (the same integers as the player). A job with M0/M1 comes here too: its
resume key or frame comes once the machine rests at each.

The run is simulated twice: first as it is (where the job's first event falls: tick 0), then with the requests,
pressed and placed as codegen/verify/hold_search.py says: each request's first dilated event is the candidate the
simulated pulses agree with, and reported. Everything after follows from it: the times of every pulse, where the
machine comes to rest, and the limits over the whole run (checks.py); the ramp and the ceilings are held to their own
rules, from the job's settings (hold_limits.py). An ATmega2560's flash image or stream is compared a chapter at a
time, in memory that does not grow with the print (codegen/verify/hold_bounded.py), where its host keeps only its
tables."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from codegen.errors import BuildError
from codegen.pipeline.host import HostBuild
from codegen.tables.hold import F_ONE, override_target, pause_events
from codegen.verify.compare import compare
from codegen.verify.hold_bounded import held_bounded
from codegen.verify.hold_limits import ceiling_problems, ceiling_shares, ramp_problems, ramp_watch
from codegen.verify.hold_runs import FlashRun, HeatedRun, S51FlashRun, StreamRun
from codegen.verify.hold_search import CANDIDATES, FirstCycles, KeyAction, Requests, dilated_clock, key_actions


def _event_cycles(host: HostBuild, trace) -> np.ndarray:
    """The simulated cycle of every twin event's first pulse (-1 for events without one, or all -1 if the pulses
    do not pair up)."""
    twin = host.pulses
    out = np.full(len(twin.event_tick), -1, dtype=np.int64)
    order = np.argsort(trace.step_cycle, kind="stable")
    cycle, motor = trace.step_cycle[order], trace.step_motor[order]
    sim_of_pulse = np.empty(len(twin.motor), dtype=np.int64)
    for m in range(len(host.kin.motors)):
        mine, theirs = cycle[motor == m], np.flatnonzero(twin.motor == m)
        if len(mine) != len(theirs):
            return out
        sim_of_pulse[theirs] = mine
    first = np.unique(twin.event, return_index=True)
    out[first[0]] = sim_of_pulse[first[1]]
    return out


def hold_verify(host: HostBuild, image, hold_s: float | None, override: int | None, setup=None,
                steps_csv: Path | None = None) -> tuple[dict, object]:
    """The verdict (verify's JSON, with `hold`; a stream's with `link`) and the run's trace. `setup`: the
    streaming firmware's (codegen/pipeline/streaming.py), else the flash image. A host that keeps only its tables
    (host_build keep="tables": an ATmega2560's flash image or stream) is compared in bounded memory
    (codegen/verify/hold_bounded.py): its trace has no table pulses, and `steps_csv` gets --trace's rows as they
    are compared."""
    if host.hold_plan is None:
        raise BuildError("verify --hold/--override: the job has no machine.feed_hold (the image has no hold keys)")
    top = host.hold_plan.max_step * 10
    if override is not None and (override % 10 or not 10 <= override <= top):
        raise BuildError(f"verify --override {override}: the feed keys step by 10 % from 10 % to {top} % "
                         "(machine.feed_hold.max_override)")
    if hold_s is not None and not 0 <= hold_s < host.totals.duration_s:
        raise BuildError(f"verify --hold {hold_s:g}: the job plays {host.totals.duration_s:.4f} s (hold within that)")
    if setup is not None:
        runner = StreamRun(host, image, setup)
    elif host.target.target == "mcs51":
        runner = S51FlashRun(host, image)
    else:
        runner = HeatedRun(host, image) if host.heaters else FlashRun(host, image)
    tick0 = runner.tick0(bool(pause_events(host.schedule)))
    actions = key_actions(host, tick0, hold_s, override)
    resume_target = override_target((override or host.job.machine.feed_hold.override) // 10)
    requests = Requests(host, tick0, actions, resume_target, runner.candidates or CANDIDATES)
    presses = requests.presses()
    slower = 1.0 if override is None else 11.0
    held = held_bounded if host.pulses is None else _held_whole
    compared, ramp, parks, resume_arrived, shares = held(host, runner, requests, presses, slower, steps_csv)
    trace = compared.trace
    result = runner.result(compared.verdict, trace, compared if host.pulses is None else None)
    result["hold"] = _report(host, actions, parks, ramp.highest_factor, tick0, resume_arrived, override, shares)
    limits = ramp_problems(host, ramp) + ceiling_problems(shares)  # the dilated twin shares these: first
    result["problems"][:0] = limits
    result["pass"] = result["pass"] and not limits
    expected = sum(function == "resume" for function, _ in presses)
    if len(parks) != expected:
        result["problems"].append(f"the machine came to rest {len(parks)} times, "
                                  f"{expected} expected (the hold and every M0/M1)")
        result["pass"] = False
    return result, trace


def _held_whole(host: HostBuild, runner, requests: Requests, presses: list[tuple[str, int]], slower: float,
                steps_csv: Path | None = None):
    """The run simulated into one trace with every pulse, compared with the whole dilated twin at once (held_bounded's
    answer; `steps_csv` is written by the caller)."""
    trace, arrived = runner.run(presses, slower)
    for a, when in zip(requests.actions, arrived):
        a.press = when  # a frame reaches the firmware when its last byte has arrived
    resume_arrived = arrived[len(requests.actions):]
    sim = FirstCycles.whole(_event_cycles(host, trace.run_only()))  # homing steps are not the table's
    dilator = requests.place(sim, resume_arrived)
    final = dilator.window(0, dilator.events)
    twin = host.pulses
    dilated = dataclasses.replace(twin, tick=final.tick[twin.event], event_tick=final.tick, motor_tick=None,
                                  motor_dir=None, motor_first=None)
    warp = dilated_clock(host.events.time, twin.event_tick, final.tick, host.target.tick_hz)
    verdict = compare(host, trace, runner.switches, streamed=runner.streamed, dilated=dilated, warp=warp,
                      dilation=final)
    ramp = ramp_watch(host)
    ramp.add(final, 0)
    return WholeRun(verdict, trace), ramp, final.parks, resume_arrived, ceiling_shares(host)


@dataclasses.dataclass
class WholeRun:
    """What _held_whole's comparison found: its verdict and the trace with every pulse."""

    verdict: object
    trace: object


def pauses(host: HostBuild) -> bool:
    """The job has M0/M1 pauses: its verification presses the resume key (hold_verify)."""
    return host.hold_plan is not None and bool(pause_events(host.schedule))


def hold_lines(hold: dict) -> list[str]:
    """verify's text lines for a held or overridden run."""
    lines = [f"  {k['key']} at {k['pressed_s']:.4f} s: the player dilated from event {k['first_dilated_event']}"
             for k in hold["keys"]]
    if (hold.get("override_pct") or 0) > 100:
        at_ceilings = (f" (at them a motor would run at {100 * hold['ceiling_rate_ratio']:.1f} % of its rate at most)"
                       if hold["ceiling_rate_ratio"] else "")
        lines.append(f"  override {hold['override_pct']} %: the factor went up to {hold['highest_factor_pct']:.1f} %, "
                     f"under {hold['ceiling_records']} ceiling records{at_ceilings}")
    if "at_rest_s" in hold:
        lines.append(f"  hold: at rest {hold['stopping_s']:.4f} s after the key (at {hold['at_rest_s']:.4f} s, "
                     f"before event {hold['parked_event']}), resumed at {hold['resume_s']:.4f} s")
    elif hold.get("ended_before_rest"):
        lines.append(f"  hold: the job ended before the machine could come to rest (slowing from 100 % to rest "
                     f"takes {hold['ramp_s']:.4f} s or more)")
    lines += [f"  M0/M1 pause: at rest at {r['at_rest_s']:.4f} s (before event {r['parked_event']}), resumed at "
              f"{r['resume_s']:.4f} s" for r in hold["rests"] if r["kind"] == "pause"]
    return lines


def _report(host: HostBuild, actions: list[KeyAction], parks: list, highest_factor: int, tick0: int,
            resume_presses: list[int], override: int | None, shares: dict) -> dict:
    """The hold's figures; `parks`: the dilation's, `highest_factor` the highest it played, `shares`:
    ceiling_shares."""
    f_cpu, tick_hz = host.target.f_cpu, host.target.tick_hz

    def seconds(cycles: int) -> float:  # from the job's tick 0
        return round((cycles - tick0) / f_cpu, 6)

    rests = [{"kind": "pause" if paused else "hold", "at_rest_s": round(tick / tick_hz, 6),
              "parked_event": event, "resume_s": seconds(press)}
             for (event, tick, paused), press in zip(parks, resume_presses)]
    out: dict = {"override_pct": override, "factor_full_scale": F_ONE, "rests": rests,
                 "highest_factor_pct": round(100 * highest_factor / F_ONE, 1),
                 "ceiling_records": host.schedule.n_ceiling,
                 "ceiling_rate_ratio": round(max((s[0] for s in shares.values()), default=0.0), 4),
                 "ramp_s": round(host.hold_plan.ramp_seconds(tick_hz), 6), "keys": [
        {"key": a.function, "pressed_s": seconds(a.press), "first_dilated_event": a.event} for a in actions]}
    hold = next((a for a in actions if a.function == "hold"), None)
    held = next((r for r in rests if r["kind"] == "hold"), None)
    if hold is not None and held is not None:
        out.update({"hold_s": seconds(hold.press), "at_rest_s": held["at_rest_s"], "resume_s": held["resume_s"],
                    "stopping_s": round(held["at_rest_s"] - seconds(hold.press), 6),
                    "parked_event": held["parked_event"]})
    elif hold is not None:  # the job ended while the factor ramped down: every pulse still the dilated twin's
        out.update({"hold_s": seconds(hold.press), "ended_before_rest": True})
    return out
