"""`verify --hold SECONDS` and `verify --override PERCENT` on an image with machine.feed_hold: the simulator
presses the board's hold keys (an ATmega2560's or an 8051's flash image) or the host sends HOLD, RESUME, FEED_DOWN
and FEED_UP frames (a streaming firmware: codegen/verify/hold_runs.py), and every pulse is compared with the twin on the
dilated clock that codegen/tables/hold.py models (the same integers as the player). A job with M0/M1 comes here too: its
resume key or frame comes once the machine rests at each.

The run is simulated twice: first as it is (where the job's first event falls: tick 0), then with the requests.
The override requests (feed- or feed+, one per 10 %) come from 10 ms into the job, one every 100 ms; the hold at
SECONDS into the job; resume once the twin says the machine is at rest (REST_S after its park). A request is seen
by main's poll after a step interrupt, and that event's next interrupt dilates the event after it: which event that
is depends on cycles the twin does not count, so each request's first dilated event is chosen among a few
(CANDIDATES) as the one the simulated pulses agree with, and reported. Everything after follows from it: the
times of every pulse, where the machine comes to rest, and the limits over the whole run (checks.py); the ramp and
the ceilings are held to their own rules, from the job's settings (hold_limits.py)."""

from __future__ import annotations

import dataclasses

import numpy as np

from codegen.errors import BuildError
from codegen.pipeline.host import HostBuild
from codegen.tables.hold import F_ONE, RESUME_TICKS, Dilation, dilate, override_target, pause_events
from codegen.verify.compare import compare
from codegen.verify.hold_limits import ceiling_problems, ceiling_shares, ramp_problems
from codegen.verify.hold_runs import FlashRun, HeatedRun, S51FlashRun, StreamRun

OVERRIDE_FIRST_S, OVERRIDE_EVERY_S = 0.01, 0.1  # the override key presses from the job's start
REST_S = 0.02  # from the park the twin predicts to the resume key
POLL_CYCLES = 400  # a step interrupt and main's poll: a key pressed this long before an event may be seen after it
CANDIDATES = 5  # events, after the first one within POLL_CYCLES of the press, that may be the key's first
# (a runner may need more: its `candidates`)
RESUME_FIT = 32  # events after a resume whose earliest pulse places it (some may come late behind a link interrupt)


@dataclasses.dataclass
class KeyAction:
    function: str  # hold, feed-, feed+
    target: int  # the factor the key sets (F)
    press: int  # cycles from reset
    event: int | None = None  # its first dilated event, once known


def _actions(host: HostBuild, tick0: int, hold_s: float | None, override: int | None) -> list[KeyAction]:
    f_cpu, start = host.target.f_cpu, host.job.machine.feed_hold.override // 10
    actions = []
    if override is not None:
        goal = override // 10
        for i, step in enumerate(range(start, goal, 1 if goal > start else -1)):
            press = tick0 + int((OVERRIDE_FIRST_S + i * OVERRIDE_EVERY_S) * f_cpu)
            nxt = step + (1 if goal > start else -1)
            actions.append(KeyAction("feed+" if goal > start else "feed-", override_target(nxt), press))
    if hold_s is not None:
        last = (actions[-1].press - tick0) / f_cpu + OVERRIDE_EVERY_S if actions else 0.0
        if hold_s < last:
            raise BuildError(f"verify --hold {hold_s:g}: the override's requests go on until {last:g} s into the "
                             "job; hold after them")
        actions.append(KeyAction("hold", 0, tick0 + int(hold_s * f_cpu)))
    return actions


def _predict(host: HostBuild, actions: list[KeyAction], events: list[int], resumes: list[int],
             resume_target: int) -> Dilation:
    """The twin on the dilated clock; an image that starts below 100 % dilates from its first event on."""
    start = override_target(host.job.machine.feed_hold.override // 10)
    changes = ([(0, start)] if start != F_ONE else []) + [(e, a.target) for a, e in zip(actions, events)]
    return dilate(host.schedule, host.hold_plan, changes, resumes, resume_target)


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


def hold_verify(host: HostBuild, image, hold_s: float | None, override: int | None,
                setup=None) -> tuple[dict, object]:
    """The verdict (verify's JSON, with `hold`; a stream's with `link`) and the run's trace. `setup`: the
    streaming firmware's (codegen/pipeline/streaming.py), else the flash image."""
    if host.hold_plan is None:
        raise BuildError("verify --hold/--override: the job has no machine.feed_hold (the image has no hold keys)")
    top = host.hold_plan.max_step * 10
    if override is not None and (override % 10 or not 10 <= override <= top):
        raise BuildError(f"verify --override {override}: the feed keys step by 10 % from 10 % to {top} % "
                         "(machine.feed_hold.max_override)")
    if hold_s is not None and not 0 <= hold_s < host.plan.total:
        raise BuildError(f"verify --hold {hold_s:g}: the job plays {host.plan.total:.4f} s (hold within that)")
    if setup is not None:
        runner = StreamRun(host, image, setup)
    elif host.target.target == "mcs51":
        runner = S51FlashRun(host, image)
    else:
        runner = HeatedRun(host, image) if host.heaters else FlashRun(host, image)
    target, f_cpu = host.target, host.target.f_cpu
    prescale, latency = f_cpu // target.tick_hz, int(target.mcu_data.get("isr_latency_cycles", 0))
    least_latency = int(target.mcu_data.get("isr_latency_min_cycles", latency))
    candidates = runner.candidates or CANDIDATES
    tick0 = runner.tick0(bool(pause_events(host.schedule)))
    actions = _actions(host, tick0, hold_s, override)
    resume_target = override_target((override or host.job.machine.feed_hold.override) // 10)

    def cycles_of(d: Dilation) -> np.ndarray:
        """Every event's predicted cycle; one never played (after a park without its resume): the end of time, so
        that the predictions stay sorted for searchsorted."""
        return np.where(d.tick >= 0, tick0 + d.tick * prescale + latency, np.iinfo(np.int64).max)

    # Where each request is first seen (the middle candidate, to place those that follow and the resumes), on the
    # clock of the requests before it and of the M0/M1 pauses before it, each resumed as _resume_presses says.
    guess: list[int] = []
    for a in actions:
        done = actions[:len(guess)]
        resumes = [(r - tick0) // prescale + RESUME_TICKS
                   for r in _resume_presses(host, done, guess, resume_target, tick0, prescale, candidates)]
        pred = cycles_of(_predict(host, done, guess, resumes, resume_target))
        first = int(np.searchsorted(pred, a.press - POLL_CYCLES))
        guess.append(first + candidates // 2 + 1)
    resume_presses = _resume_presses(host, actions, guess, resume_target, tick0, prescale, candidates)
    presses = [(a.function, a.press) for a in actions] + [("resume", r) for r in resume_presses]
    trace, arrived = runner.run(presses, 1.0 if override is None else 11.0)
    for a, when in zip(actions, arrived):
        a.press = when  # a frame reaches the firmware when its last byte has arrived
    resume_arrived = arrived[len(actions):]

    # The resumed events' ticks, then each request's first dilated event: the candidate the pulses agree with.
    sim = _event_cycles(host, trace.run_only())  # homing steps are not the table's

    def resumed(events: list[int]) -> list[int]:
        """Each park's resumed tick: the one that puts the first pulses after its resume in place (everything
        after a resume moves with it), at the player's least latency: the earliest of RESUME_FIT pulses (a link
        interrupt may have delayed the first)."""
        ticks: list[int] = []
        for r in resume_arrived:
            provisional = (r - tick0) // prescale + RESUME_TICKS
            d = _predict(host, actions[:len(events)], events, ticks + [provisional], resume_target)
            if r < 0 or len(d.parks) <= len(ticks):
                break
            until = d.parks[len(ticks) + 1][0] if len(d.parks) > len(ticks) + 1 else len(sim)
            index = np.arange(len(sim))
            after = np.flatnonzero((sim > r) & (index >= d.parks[len(ticks)][0]) & (index < until))[:RESUME_FIT]
            if not len(after):
                break
            late = (sim[after] - tick0 - least_latency) / prescale - d.tick[after]
            ticks.append(provisional + int(round(float(late.min()))))
        return ticks

    chosen: list[int] = []
    for i, a in enumerate(actions):
        pred = cycles_of(_predict(host, actions[:i], chosen, resumed(chosen), resume_target))
        first = int(np.searchsorted(pred, a.press - POLL_CYCLES))
        # the pulses before the next request can tell (it has not come yet)
        before = (sim >= 0) & (sim < (actions[i + 1].press if i + 1 < len(actions) else np.inf))
        best, best_err = first + 1, None
        for n in range(first + 1, first + 1 + candidates):
            d = _predict(host, actions[:i + 1], chosen + [n], resumed(chosen + [n]), resume_target)
            err = int(np.abs(cycles_of(d)[before] - sim[before]).max()) if before.any() else 0
            if best_err is None or err < best_err:
                best, best_err = n, err
        chosen.append(best)
        a.event = best
    final = _predict(host, actions, chosen, resumed(chosen), resume_target)
    twin = host.pulses
    dilated = dataclasses.replace(twin, tick=final.tick[twin.event], event_tick=final.tick, motor_tick=None,
                                  motor_dir=None, motor_first=None)
    plan_time = host.events.time
    delay = (final.tick - twin.event_tick) / target.tick_hz

    def warp(t):
        return t + np.interp(t, plan_time, delay)

    verdict = compare(host, trace, runner.switches, streamed=runner.streamed, dilated=dilated, warp=warp,
                      dilation=final)
    result = runner.result(verdict, trace)
    shares = ceiling_shares(host)
    result["hold"] = _report(host, actions, final, tick0, resume_arrived, override, shares)
    limits = ramp_problems(host, final) + ceiling_problems(shares)  # the dilated twin shares these: first
    result["problems"][:0] = limits
    result["pass"] = result["pass"] and not limits
    if len(final.parks) != len(resume_presses):
        result["problems"].append(f"the machine came to rest {len(final.parks)} times, "
                                  f"{len(resume_presses)} expected (the hold and every M0/M1)")
        result["pass"] = False
    return result, trace


def pauses(host: HostBuild) -> bool:
    """The job has M0/M1 pauses: its verification presses the resume key (hold_verify)."""
    return host.hold_plan is not None and bool(pause_events(host.schedule))


def _resume_presses(host: HostBuild, actions: list[KeyAction], guess: list[int], resume_target: int, tick0: int,
                    prescale: int, candidates: int = CANDIDATES) -> list[int]:
    """The resume key's presses: REST_S after each park the twin predicts (a hold's: the latest of its
    candidates), in order; each predicted resume is RESUME_TICKS after its press."""
    f_cpu, presses, resumes = host.target.f_cpu, [], []
    hold = next((i for i, a in enumerate(actions) if a.function == "hold"), None)
    while True:
        d = _predict(host, actions, guess, resumes, resume_target)
        if len(d.parks) <= len(resumes):
            return presses
        event, tick, paused = d.parks[len(resumes)]
        if not paused and hold is not None:  # the hold's park: the latest of its candidates
            for k in range(candidates):
                other = guess[:hold] + [guess[hold] - candidates // 2 + k] + guess[hold + 1:]
                parks = _predict(host, actions, other, resumes, resume_target).parks
                if len(parks) > len(resumes):
                    tick = max(tick, parks[len(resumes)][1])
        press = tick0 + tick * prescale + int(REST_S * f_cpu)
        presses.append(press)
        resumes.append((press - tick0) // prescale + RESUME_TICKS)


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


def _report(host: HostBuild, actions: list[KeyAction], final: Dilation, tick0: int, resume_presses: list[int],
            override: int | None, shares: dict) -> dict:
    """The hold's figures; `shares`: ceiling_shares."""
    f_cpu, tick_hz = host.target.f_cpu, host.target.tick_hz

    def seconds(cycles: int) -> float:  # from the job's tick 0
        return round((cycles - tick0) / f_cpu, 6)

    rests = [{"kind": "pause" if paused else "hold", "at_rest_s": round(tick / tick_hz, 6),
              "parked_event": event, "resume_s": seconds(press)}
             for (event, tick, paused), press in zip(final.parks, resume_presses)]
    played = final.factor[final.factor >= 0]
    out: dict = {"override_pct": override, "factor_full_scale": F_ONE, "rests": rests,
                 "highest_factor_pct": round(100 * int(played.max(initial=0)) / F_ONE, 1),
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
