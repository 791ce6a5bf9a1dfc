"""The deliberate bugs of scripts/mutation_test.py: each one exact text of one file of the repository replaced by
another, the job (and verify flags) that exercises it, and the words of a message that names the fault.

The kinds follow /work/shared/VERIFY-MUTANTS.md (its 49 of today's main): 29 in the firmware templates, 20 in the
host code; and one more, the table encoder's bug of a flash image's mutant in a stream's bytes (50). Where a job
did not reach its mutant (its output unchanged), the mutant runs on a job that does. tests/test_mutants_apply.py
checks that every `old` text is found exactly once in today's sources.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Mutant:
    name: str
    path: str  # the file, from the repository's top
    old: str  # exact text, found exactly once in the file
    new: str
    job: str  # the job file verify runs, from the repository's top
    flags: tuple[str, ...] = ()  # more verify options (--hold 1.0, --stream, ...)
    names: tuple[str, ...] = ()  # a problem naming the fault contains one of these (any case)


AVR_JOB = "tests/data/mutants/avr-home.yaml"  # RAMPS, homes x and y, out and back with pen moves
SEED_JOB = "tests/data/mutants/seed51-home.yaml"  # the 8051 seed board: L297s, HALF/FULL held, LCD
AT89_JOB = "tests/data/mutants/at89-home.yaml"  # a bare AT89C52: enables active low on P2
LASER_JOB = "examples/laser/power.yaml"  # M3 and M4 cuts, their power changed mid-cut
LASER_END_JOB = "tests/data/mutants/laser-end.yaml"  # its G-code ends in a cut, the laser still on
GCODE_JOB = "examples/gcode/mixed.yaml"  # IJK and R arcs, G20, G92, F words
OFFSETS_JOB = "tests/data/mutants/gcode-offsets.yaml"  # F on arc lines (read in Python), G92 to non-zero values
DELTA_JOB = "tests/data/mutants/delta-gcode.yaml"  # a Kossel mini's G-code moves: the reference reads them again
LIMITS_JOB = "examples/ellipse.yaml"  # runs at 98 % of its motors' rate and 97 % of their acceleration
HOLD_JOB = "examples/star.yaml"  # corexy with feed hold and override keys
NEAR_RATE_JOB = "tests/data/mutants/override-near-rate.yaml"  # feed hold; x cruises at 92.5 % of its rate: no headroom
CORNERS_JOB = "tests/data/mutants/corners.yaml"  # polygons whose corners bind on the junction deviation
WINDOWS_JOB = "tests/data/mutants/windows.yaml"  # x moves and y moves in lookahead windows of their own

AVR_PLAYER, AVR_HOMING, AVR_BLOCK = "templates/avr/player.c.j2", "templates/avr/homing.c.j2", \
    "templates/avr/player_isr/block.S.j2"
AVR_CORE, AVR_LASER = "templates/avr/player_isr/core_macros.j2", "templates/avr/laser.h.j2"
MCS51_PLAYER, MCS51_HOMING = "templates/mcs51/player.c.j2", "templates/mcs51/homing.c.j2"
AVR_ENABLE = "    PORT{{ port }} {{ '&= ~' if enable_active_low else '|= ' }}({{ bits }});"
AVR_DISABLE = "    PORT{{ port }} {{ '|= ' if enable_active_low else '&= ~' }}({{ bits }});"
MCS51_ENABLE = ("    {{ sfr }} {{ '&= ' ~ ((255 - mask) | hex) if enable_active_low else '|= ' ~ (mask | hex) }}; "
                "/* drivers on */\n")
MCS51_DISABLE = "    {{ sfr }} {{ '|= ' ~ (mask | hex) if enable_active_low else '&= ' ~ ((255 - mask) | hex) }};"
DIR_FIRST = "    ; the new block's DIR pins, then the tool\n{{ write_pins(dir_ports).rstrip() }}\n"
FALL = "{{ pulse_end(\"block path\").rstrip() }}\n"

FIRMWARE = [
    Mutant("avr ENABLE never asserted", AVR_PLAYER, AVR_ENABLE, AVR_DISABLE, AVR_JOB, names=("ENABLE",)),
    Mutant("avr drivers disabled after homing", AVR_HOMING, "    TCCR1B = 0;\n    TCNT1 = 0;\n}\n",
           "    TCCR1B = 0;\n    TCNT1 = 0;\n{% for port, bits in enable_ports %}\n" + AVR_DISABLE + "\n{% endfor %}\n}\n",
           AVR_JOB, names=("ENABLE",)),
    Mutant("avr ENABLE never asserted (stream)", "templates/avr/stream.c.j2", AVR_ENABLE, AVR_DISABLE, AVR_JOB,
           ("--stream",), names=("ENABLE",)),
    Mutant("avr tool on at reset", AVR_PLAYER, "PORT{{ tool.port }} {{ '&= ~' if tool.active_high else '|= ' }}",
           "PORT{{ tool.port }} {{ '|= ' if tool.active_high else '&= ~' }}", AVR_JOB, names=("tool is on",)),
    Mutant("avr homing slow approach at the fast interval", AVR_HOMING,
           "phase == PHASE_SLOW ? {{ h.id }}_HOME_SLOW_TICKS", "phase == PHASE_SLOW ? {{ h.id }}_HOME_FAST_TICKS",
           AVR_JOB, names=("slow approach",)),
    Mutant("avr homing direction", AVR_HOMING,
           "        if (towards)\n            PORT{{ m.dir.port }} {{ '|= ' if m.towards_high else '&= ~' }}",
           "        if (towards)\n            PORT{{ m.dir.port }} {{ '&= ~' if m.towards_high else '|= ' }}",
           AVR_JOB, names=("homing failed",)),
    Mutant("avr homing back off half as long", AVR_HOMING, "_made >= {{ h.id }}_HOME_BACKOFF_STEPS &&",
           "_made >= {{ h.id }}_HOME_BACKOFF_STEPS / 2 &&", AVR_JOB, names=("homed in",)),
    Mutant("avr homing pause an eighth", AVR_HOMING, "    wait_ticks(PAUSE_TICKS); /*",
           "    wait_ticks(PAUSE_TICKS / 8); /*", AVR_JOB, names=("homing",)),
    Mutant("avr homing switch polarity", AVR_HOMING,
           "closed ? ({{ h.id }}_SWITCH_CLOSED_HIGH ? {{ h.id }}_SWITCH_BIT : 0)",
           "closed ? ({{ h.id }}_SWITCH_CLOSED_HIGH ? 0 : {{ h.id }}_SWITCH_BIT)", AVR_JOB, names=("homed in", "homing")),
    Mutant("avr homing STEP pulse a quarter", AVR_HOMING, "__builtin_avr_delay_cycles(STEP_PULSE_CYCLES);",
           "__builtin_avr_delay_cycles(STEP_PULSE_CYCLES / 4);", AVR_JOB, names=("STEP pulse",)),
    Mutant("avr DIR written while STEP is high", AVR_BLOCK, FALL + DIR_FIRST, DIR_FIRST + FALL, AVR_JOB,
           names=("DIR changes",)),
    Mutant("avr run count +1", AVR_CORE, "    mov RUN_LO, T0{{ cyc(1) }}\n",
           "    mov RUN_LO, T0{{ cyc(1) }}\n    inc RUN_LO\n", AVR_JOB, names=("steps, the twin",)),
    Mutant("avr STEP pulse half as long", AVR_CORE, "{{ pad(pulse_cycles + 1 - ns.c",
           "{{ pad(pulse_cycles // 2 + 1 - ns.c", AVR_JOB, names=("STEP pulse",)),
    Mutant("avr Timer1 prescaler 64", "templates/avr/config.h.j2", "#define TIMER1_CLOCK_BITS ({{ timer_clock }})",
           "#define TIMER1_CLOCK_BITS ({{ timer_clock }} | _BV(CS10))", AVR_JOB,
           names=("predicted time", "the homing settings give")),
    Mutant("avr laser PWM period 17/16", AVR_LASER, "    ICR5 = LASER_TOP;", "    ICR5 = LASER_TOP + LASER_TOP / 16;",
           LASER_JOB, names=("PWM", "laser")),
    Mutant("avr laser on at reset", AVR_LASER, "    {{ laser.ocr }} = 0;\n    ICR5",
           "    {{ laser.ocr }} = LASER_TOP / 2;\n    ICR5", LASER_JOB, names=("laser",)),
    Mutant("avr laser left on at the end", AVR_BLOCK, "{% if laser %}\n{{ laser_zero() }}\n{% endif %}\n", "",
           LASER_END_JOB, names=("laser",)),
    Mutant("mcs51 ENABLE never asserted (active low)", MCS51_PLAYER, MCS51_ENABLE, "", AT89_JOB, names=("ENABLE",)),
    Mutant("mcs51 ENABLE driven off (L297, active high)", MCS51_PLAYER, MCS51_ENABLE,
           MCS51_DISABLE + " /* drivers on */\n", SEED_JOB, names=("ENABLE",)),
    Mutant("mcs51 drivers disabled from homing on", MCS51_HOMING, "    TR1 = 1; /* the first phase's",
           "{% for sfr, mask in enable_ports %}\n" + MCS51_DISABLE + "\n{% endfor %}\n    TR1 = 1; /* the first phase's",
           SEED_JOB, names=("ENABLE",)),
    Mutant("mcs51 tool on at reset", MCS51_PLAYER,
           "{{ tool.sfr }} {{ '&= ' ~ ((255 - tool.mask) | hex) if tool.active_high else '|= ' ~ (tool.mask | hex) }}",
           "{{ tool.sfr }} {{ '|= ' ~ (tool.mask | hex) if tool.active_high else '&= ' ~ ((255 - tool.mask) | hex) }}",
           SEED_JOB, names=("tool is on",)),
    Mutant("mcs51 L297 HALF/FULL low", MCS51_PLAYER,
           "{{ h.sfr }} {{ '|= ' ~ (h.mask | hex) if h.level else '&= ' ~ ((255 - h.mask) | hex) }}",
           "{{ h.sfr }} {{ '&= ' ~ ((255 - h.mask) | hex) if h.level else '|= ' ~ (h.mask | hex) }}",
           SEED_JOB, names=("HALF/FULL",)),
    Mutant("mcs51 homing slow approach at the fast interval", MCS51_HOMING,
           "            {{ h.var }}_wait = slow ? {{ h.id }}_HOME_SLOW_TICKS",
           "            {{ h.var }}_wait = slow ? {{ h.id }}_HOME_FAST_TICKS", SEED_JOB, names=("slow approach",)),
    Mutant("mcs51 homing direction", MCS51_HOMING,
           "        if (towards)\n            {{ m.dir.sfr }} {{ '|= ' if m.towards_high else '&= ~' }}",
           "        if (towards)\n            {{ m.dir.sfr }} {{ '&= ~' if m.towards_high else '|= ' }}",
           SEED_JOB, names=("homing failed",)),
    Mutant("mcs51 homing pause an eighth", MCS51_HOMING, "    wait_ticks(PAUSE_TICKS); /*",
           "    wait_ticks(PAUSE_TICKS / 8); /*", AT89_JOB, names=("homing",)),
    Mutant("mcs51 run count +1", "templates/mcs51/player/record_macros.j2",
           "    mov _pl_cnt_lo,a\n    mov _pl_cnt_hi,#1\n", "    mov _pl_cnt_lo,a\n    inc _pl_cnt_lo\n"
           "    mov _pl_cnt_hi,#1\n", AT89_JOB, names=("steps, the twin",)),
    Mutant("mcs51 DIR inverted at block loads", "templates/mcs51/player/block.c.j2",
           "    mov {{ m.dir.name }},c ; DIR", "    cpl c\n    mov {{ m.dir.name }},c ; DIR", AT89_JOB,
           names=("wrong way",)),
    Mutant("mcs51 display units digit +1", "templates/mcs51/lcd.c.j2", "= '0' + (unsigned char)rest;",
           "= '1' + (unsigned char)rest;", SEED_JOB, names=("display",)),
    Mutant("mcs51 tool left as the last block has it", "templates/mcs51/player/block.c.j2",
           "    ; the end marker: timer off, the final tool state, halt\n    clr TR0\n    clr ET0\n    mov a,_pl_flags\n",
           "    ; the end marker: timer off, the final tool state, halt\n    clr TR0\n    clr ET0\n    mov a,#0x40\n",
           SEED_JOB, names=("tool",)),
]

HOST = [
    Mutant("planner at 105 % velocity", "codegen/motion/planner.py", "    vmax = motor.max_velocity * keep *",
           "    vmax = 1.05 * motor.max_velocity * keep *", LIMITS_JOB, names=("rate",)),
    Mutant("planner at 105 % acceleration", "codegen/motion/planner.py",
           "    amax = motor.max_accel * keep * limits.accel_share",
           "    amax = 1.05 * motor.max_accel * keep * limits.accel_share", LIMITS_JOB, names=("acceleration",)),
    Mutant("junction speed v^2 doubled", "codegen/motion/planner.py", "a_normal * deviation * sin_half /",
           "2.0 * a_normal * deviation * sin_half /", CORNERS_JOB, names=("junction", "corner")),
    Mutant("R arc centre on the wrong side", "codegen/gcode/arcs.py", "    if not clockwise:\n        h_x2_div_d",
           "    if clockwise:\n        h_x2_div_d", GCODE_JOB, names=("arc",)),
    Mutant("R arc centre +0.05 mm", "codegen/gcode/arcs.py", "    center = (start[0] + 0.5 * (x - y * h_x2_div_d),",
           "    center = (start[0] + 0.5 * (x - y * h_x2_div_d) + 0.05,", GCODE_JOB, names=("arc",)),
    Mutant("G20 = 25.0 mm", "codegen/gcode/interpreter.py", "            self.unit = 25.4",
           "            self.unit = 25.0", GCODE_JOB, names=("G20", "inch")),
    Mutant("G92 sign", "codegen/gcode/moves.py", "self.off[i] = self.pos[i] - params[",
           "self.off[i] = self.pos[i] + params[", OFFSETS_JOB, names=("G92",)),
    Mutant("F words per 50 s", "codegen/gcode/interpreter.py", "        self.feed = value * self.unit / 60.0",
           "        self.feed = value * self.unit / 50.0", OFFSETS_JOB, names=("feed",)),
    Mutant("steps floored, not rounded", "codegen/kinematics/base.py",
           "        return np.round(self.to_motor(axes) * self.limits.steps_per_mm)",
           "        return np.floor(self.to_motor(axes) * self.limits.steps_per_mm)", "examples/arc.yaml",
           names=("ends at step", "path")),
    Mutant("hold ramp twice as steep", "codegen/tables/hold.py", "    ramp_k = int(RAMP_SHARE * per_second",
           "    ramp_k = int(2 * RAMP_SHARE * per_second", HOLD_JOB, ("--hold", "1.0"), names=("ramp", "hold")),
    Mutant("override ceiling from 105 % of headroom", "codegen/tables/headroom.py",
           "    allow = 1.0 / _rate_ratio(", "    allow = 1.05 / _rate_ratio(", NEAR_RATE_JOB, ("--override", "150"),
           names=("rate", "ceiling")),
    Mutant("laser power x 0.95", "codegen/tables/laser.py", "    power = np.where(on, segments.power[segment], 0.0)",
           "    power = np.where(on, 0.95 * segments.power[segment], 0.0)", LASER_JOB, names=("power",)),
    Mutant("rate-run window 50 % of the gap", "codegen/tables/compress.py", "    share: float = 0.05",
           "    share: float = 0.5", LIMITS_JOB, names=("window", "timing")),
    Mutant("each window's twin from clock 0", "codegen/pipeline/windows.py",
           "pulses = predict(compressed.schedule, before.origin_fx, before.position)",
           "pulses = predict(compressed.schedule, 0, before.position)", WINDOWS_JOB, names=("twin",)),
    Mutant("short runs' add +1/256 tick in the bytes", "codegen/tables/format.py",
           "    runs[rs, 4:6] = _le(add[rs] & 0xFFFF, 2)", "    runs[rs, 4:6] = _le((add[rs] + 1) & 0xFFFF, 2)",
           LIMITS_JOB, names=("predicted time", "the image's table")),
    Mutant("short runs' add +1/256 tick in the streamed bytes", "codegen/tables/format.py",
           "    runs[rs, 4:6] = _le(add[rs] & 0xFFFF, 2)", "    runs[rs, 4:6] = _le((add[rs] + 1) & 0xFFFF, 2)",
           "examples/gcode/plotter-svg.yaml", ("--stream",), names=("streamed table",)),
    Mutant("homing fast interval from the slow speed", "codegen/program/homing.py",
           "fast_interval=max(1, round(tick_hz / (settings.speed * spm)))",
           "fast_interval=max(1, round(tick_hz / (settings.slow_speed * spm)))", AVR_JOB, names=("homing",)),
    Mutant("homing back off twice as far", "codegen/program/homing.py",
           "backoff_steps=max(1, round(settings.backoff * spm))",
           "backoff_steps=max(1, round(2 * settings.backoff * spm))", AVR_JOB, names=("homing", "back off")),
    Mutant("delta rods 0.5 mm long", "codegen/kinematics/delta.py", "        self.rod2 = float(diagonal_rod) ** 2",
           "        self.rod2 = float(diagonal_rod + 0.5) ** 2", DELTA_JOB, names=("path", "rod", "G-code line")),
    Mutant("the tool of the blocks inverted", "codegen/tables/compress.py",
           "        block_tool=events.block_tool.astype(bool),", "        block_tool=~events.block_tool.astype(bool),",
           AVR_JOB, names=("tool",)),
    Mutant("G4 P read as tenths of a second", "codegen/gcode/dialect.py",
           "        return 1.0 if grbl else 0.001", "        return 1.0 if grbl else 0.01", GCODE_JOB,
           names=("dwell", "G4")),
]

MUTANTS = FIRMWARE + HOST
