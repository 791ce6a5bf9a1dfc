"""The windows' results joined into the whole program's (for a build whose tables go into one image, and
for `verify`, which compares every pulse): segment, block, run and event indices counted over the program.
"""

from __future__ import annotations

import numpy as np

from codegen.motion.blocks import Events
from codegen.motion.planner import Plan
from codegen.pipeline.windows import Played
from codegen.tables.compress import Compressed
from codegen.tables.schedule import Schedule
from codegen.tables.twin import Pulses
from codegen.toolpath.segments import Segments, concat


def _offsets(sizes: list[int]) -> list[int]:
    return np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64).tolist() if sizes else []


def _cat(parts: list, name: str) -> np.ndarray:
    return np.concatenate([getattr(p, name) for p in parts])


def join_segments(played: list[Played], planned: bool = False) -> Segments:
    """`planned`: a shaped job's segments before shaping (else the blocks' own; an unshaped window's are its plan's)."""
    return concat(*(_source(p, planned).segments for p in played))


def join_plan(played: list[Played], planned: bool = False) -> Plan:
    return Plan.join([_source(p, planned).plan for p in played])


def _source(played: Played, planned: bool):
    return played.planned if planned and played.planned is not None else played.window


def join_events(played: list[Played]) -> Events:
    events = [p.events for p in played]
    segment_at = _offsets([len(p.window.segments) for p in played])
    event_at = _offsets([len(e.time) for e in events])
    return Events(
        block_segment=np.concatenate([e.block_segment + s for e, s in zip(events, segment_at)]),
        block_steps=_cat(events, "block_steps"), block_modulus=_cat(events, "block_modulus"),
        block_init=_cat(events, "block_init"), block_tool=_cat(events, "block_tool"),
        block_first=np.concatenate([e.block_first[:-1] + k for e, k in zip(events, event_at)]
                                   + [[sum(len(e.time) for e in events)]]).astype(np.int64),
        time=_cat(events, "time"), phase=_cat(events, "phase"),
    )


def join_schedule(played: list[Played], final_tool: bool) -> Schedule:
    schedules = [p.compressed.schedule for p in played]
    segment_at = _offsets([len(p.window.segments) for p in played])
    first = schedules[0]
    return Schedule(
        motors=first.motors, tick_hz=first.tick_hz,
        block_dirs=_cat(schedules, "block_dirs"), block_steps=_cat(schedules, "block_steps"),
        block_modulus=_cat(schedules, "block_modulus"), block_init=_cat(schedules, "block_init"),
        block_tool=_cat(schedules, "block_tool"), block_events=_cat(schedules, "block_events"),
        block_segment=np.concatenate([s.block_segment + k for s, k in zip(schedules, segment_at)]),
        run_interval=_cat(schedules, "run_interval"), run_add=_cat(schedules, "run_add"),
        run_count=_cat(schedules, "run_count"), final_tool=final_tool, run_power=_join_records(schedules, "run_power"),
        run_ceiling=_join_records(schedules, "run_ceiling"),
    )


def _join_records(schedules: list[Schedule], name: str) -> np.ndarray:
    """The runs' power or ceiling records over the program (-1 for a window's runs without any; empty: a program
    without)."""
    if not any(len(getattr(s, name)) for s in schedules):
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([getattr(s, name) if len(getattr(s, name)) else np.full(s.n_runs, -1, dtype=np.int64)
                           for s in schedules])


def join_pulses(played: list[Played]) -> Pulses:
    pulses = [p.pulses for p in played]
    event_at = _offsets([len(p.event_tick) for p in pulses])
    block_at = _offsets([p.compressed.schedule.n_blocks for p in played])
    return Pulses(
        tick=_cat(pulses, "tick"), motor=_cat(pulses, "motor"), dir=_cat(pulses, "dir"),
        event=np.concatenate([p.event + k for p, k in zip(pulses, event_at)]),
        event_tick=_cat(pulses, "event_tick"),
        event_block=np.concatenate([p.event_block + k for p, k in zip(pulses, block_at)]),
        event_position=np.concatenate([p.event_position for p in pulses]),
    )


def join_compressed(played: list[Played], final_tool: bool, pulses: Pulses) -> Compressed:
    """The emitted ticks are the twin's (the player's own)."""
    ideal = np.concatenate([p.compressed.ideal_ticks for p in played])
    return Compressed(join_schedule(played, final_tool), ideal, pulses.event_tick,
                      np.concatenate([p.compressed.window_ticks for p in played]))
