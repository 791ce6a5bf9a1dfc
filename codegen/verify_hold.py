"""`verify --hold SECONDS` and `verify --override PERCENT` on an ATmega2560 flash image with machine.feed_hold:
the simulator presses the board's hold keys, and every pulse is compared with the twin on the dilated clock that
codegen/hold.py models (the same integers as the player).

The run is simulated twice: first as it is (where the job's first event falls: tick 0), then with the keys. The
override keys (feed- or feed+, one press per 10 %) are pressed from 10 ms into the job, one every 100 ms; the hold
key at SECONDS into the job; resume once the twin says the machine is at rest (REST_S after its park). A key is
seen by main's poll after a step interrupt, and that event's next interrupt dilates the event after it: which
event that is depends on cycles the twin does not count, so each key's first dilated event is chosen among a few
(CANDIDATES) as the one the simulated pulses agree with, and reported. Everything after follows from it: the
times of every pulse, where the machine comes to rest, and the limits over the whole run (checks.py)."""

from __future__ import annotations

import dataclasses

import numpy as np

from codegen.errors import BuildError
from codegen.hold import F_ONE, Dilation, dilate, override_target
from codegen.pipeline import HostBuild
from codegen.report import verify_json
from codegen.sim.avr import simulate
from codegen.verify import compare, simulated_switches

PRESS_S = 0.05  # a key held down this long (main polls at least every 32 ms: the longest undilated wait)
OVERRIDE_FIRST_S, OVERRIDE_EVERY_S = 0.01, 0.1  # the override key presses from the job's start
REST_S = 0.02  # from the park the twin predicts to the resume key
POLL_CYCLES = 400  # a step interrupt and main's poll: a key pressed this long before an event may be seen after it
CANDIDATES = 5  # events, after the first one within POLL_CYCLES of the press, that may be the key's first


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
        if override % 10 or not 10 <= override <= 100:
            raise BuildError(f"verify --override {override}: the feed keys step by 10 % from 10 % to 100 %")
        goal = override // 10
        for i, step in enumerate(range(start, goal, 1 if goal > start else -1)):
            press = tick0 + int((OVERRIDE_FIRST_S + i * OVERRIDE_EVERY_S) * f_cpu)
            nxt = step + (1 if goal > start else -1)
            actions.append(KeyAction("feed+" if goal > start else "feed-", override_target(nxt), press))
    if hold_s is not None:
        actions.append(KeyAction("hold", 0, tick0 + int(hold_s * f_cpu)))
    return actions


def _predict(host: HostBuild, actions: list[KeyAction], events: list[int], resume_tick: int | None,
             resume_target: int) -> Dilation:
    """The twin on the dilated clock; an image that starts below 100 % dilates from its first event on."""
    start = override_target(host.job.machine.feed_hold.override // 10)
    changes = ([(0, start)] if start != F_ONE else []) + [(e, a.target) for a, e in zip(actions, events)]
    return dilate(host.schedule, host.hold_plan, changes, resume_tick, resume_target)


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


def hold_verify(host: HostBuild, image, hold_s: float | None, override: int | None) -> tuple[dict, object]:
    """The verdict (verify's JSON, with `hold`) and the keyed simulation's trace."""
    if host.hold_plan is None:
        raise BuildError("verify --hold/--override: the job has no machine.feed_hold (the image has no hold keys)")
    config, switches = host.firmware_config(), simulated_switches(host)
    target, f_cpu = host.target, host.target.f_cpu
    prescale, latency = f_cpu // target.tick_hz, int(target.mcu_data.get("isr_latency_cycles", 0))
    budget = int((host.plan.total * 1.2 + 1.0) * f_cpu)
    tick0 = simulate(image.hex_path, config, budget, switches=switches).timer_start_cycle
    if hold_s is not None and not 0 <= hold_s < host.plan.total:
        raise BuildError(f"verify --hold {hold_s:g}: the job plays {host.plan.total:.4f} s (hold within that)")
    actions = _actions(host, tick0, hold_s, override)
    resume_target = override_target((override or host.job.machine.feed_hold.override) // 10)

    def cycles_of(d: Dilation) -> np.ndarray:
        return tick0 + d.tick * prescale + latency

    # Where each key is first seen (the middle candidate, to place the presses that follow and the resume).
    guess: list[int] = []
    for a in actions:
        pred = cycles_of(_predict(host, actions[:len(guess)], guess, None, resume_target))
        first = int(np.searchsorted(pred, a.press - POLL_CYCLES))
        a.event = first + 1
        guess.append(first + CANDIDATES // 2 + 1)
    resume_press = None
    if hold_s is not None:
        parks = []
        for k in range(1, CANDIDATES + 1):
            d = _predict(host, actions, guess[:-1] + [actions[-1].event + k - 1], None, resume_target)
            if d.park_event is None:
                raise BuildError(f"verify --hold {hold_s:g}: the job ends before the machine would come to rest")
            parks.append(tick0 + d.park_tick * prescale)
        resume_press = max(parks) + int(REST_S * f_cpu)
    pins = host.hold_plan.keys
    presses = [(pins[a.function], a.press, a.press + int(PRESS_S * f_cpu)) for a in actions]
    if resume_press is not None:
        presses.append((pins["resume"], resume_press, resume_press + int(PRESS_S * f_cpu)))
    extra = int((2.0 + sum(PRESS_S for _ in presses)) * f_cpu) + (resume_press or 0)
    trace = simulate(image.hex_path, config, budget * (1 if override is None else 11) + extra,
                     switches=switches, presses=presses)

    # Each key's first dilated event: the candidate the simulated pulses agree with (in order).
    sim = _event_cycles(host, trace)
    resume_tick = None
    if resume_press is not None:
        after = np.flatnonzero(sim > resume_press)
        if len(after):
            resume_tick = int(round((sim[after[0]] - tick0 - latency) / prescale))
    chosen: list[int] = []
    for i, a in enumerate(actions):
        pred = cycles_of(_predict(host, actions[:i], chosen, None, resume_target))
        first = int(np.searchsorted(pred, a.press - POLL_CYCLES))
        # the pulses before the next key can tell (that key has not been pressed yet)
        before = (sim >= 0) & (sim < (actions[i + 1].press if i + 1 < len(actions) else np.inf))
        best, best_err = first + 1, None
        for n in range(first + 1, first + 1 + CANDIDATES):
            d = _predict(host, actions[:i + 1], chosen + [n], resume_tick, resume_target)
            err = int(np.abs(cycles_of(d)[before] - sim[before]).max()) if before.any() else 0
            if best_err is None or err < best_err:
                best, best_err = n, err
        chosen.append(best)
        a.event = best
    final = _predict(host, actions, chosen, resume_tick, resume_target)
    twin = host.pulses
    dilated = dataclasses.replace(twin, tick=final.tick[twin.event], event_tick=final.tick, motor_tick=None,
                                  motor_dir=None, motor_first=None)
    plan_time = host.events.time
    delay = (final.tick - twin.event_tick) / target.tick_hz

    def warp(t):
        return t + np.interp(t, plan_time, delay)

    verdict = compare(host, trace, switches, dilated=dilated, warp=warp)
    result = verify_json(host, verdict, image)
    result["hold"] = _report(host, actions, final, tick0, resume_press, override)
    if hold_s is not None and final.park_event is None:
        result["problems"].append("the machine did not come to rest after the hold")
        result["pass"] = False
    return result, trace


def hold_lines(hold: dict) -> list[str]:
    """verify's text lines for a held or overridden run."""
    lines = [f"  key {k['key']} at {k['pressed_s']:.4f} s: the player dilated from event {k['first_dilated_event']}"
             for k in hold["keys"]]
    if "at_rest_s" in hold:
        lines.append(f"  hold: at rest {hold['stopping_s']:.4f} s after the key (at {hold['at_rest_s']:.4f} s, "
                     f"before event {hold['parked_event']}), resumed at {hold['resume_s']:.4f} s")
    return lines


def _report(host: HostBuild, actions: list[KeyAction], final: Dilation, tick0: int, resume_press: int | None,
            override: int | None) -> dict:
    f_cpu, tick_hz = host.target.f_cpu, host.target.tick_hz
    seconds = lambda cycles: round((cycles - tick0) / f_cpu, 6)  # noqa: E731  (from the job's tick 0)
    out: dict = {"override_pct": override, "keys": [
        {"key": a.function, "pressed_s": seconds(a.press), "first_dilated_event": a.event} for a in actions]}
    hold = next((a for a in actions if a.function == "hold"), None)
    if hold is not None and final.park_event is not None:
        out.update({"hold_s": seconds(hold.press), "at_rest_s": round(final.park_tick / tick_hz, 6),
                    "stopping_s": round(final.park_tick / tick_hz - (hold.press - tick0) / f_cpu, 6),
                    "resume_s": seconds(resume_press), "parked_event": final.park_event})
    out["factor_full_scale"] = F_ONE
    return out
