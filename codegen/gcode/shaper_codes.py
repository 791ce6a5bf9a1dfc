"""M593, Marlin's input shaping: `M593 [X] [Y] [F<Hz>] [D<zeta>]` sets the shaper of the named axes (x and y when
neither is named) from its place in the program on: F its frequency (F0: unshaped), D its damping ratio.

Marlin has only ZV; here an axis keeps the shaper type the machine's `input_shaper` gives it, and an axis the
machine does not shape takes Marlin's ZV (a note at the first M593 that turns one on says so). As Klipper's
SET_INPUT_SHAPER flushes its lookahead, an M593 brings the machine to rest: the motion shaped before it settles
before the new shapers shape what follows (codegen/toolpath/segments.py). Values as Marlin's M593 takes them,
and the job key's ranges (codegen/job/schema/shaping.py); F is in Hz whatever the units (G20).
"""

from __future__ import annotations

from codegen.errors import Diagnostic
from codegen.job.schema.shaping import DEFAULT_SHAPER_DAMPING, SHAPED_AXES, SHAPER_HZ, SHAPER_MAX_DAMPING
from codegen.toolpath.items import InputShaping, ShaperSpec

MARLIN_SHAPER = "zv"  # Marlin's one shaper: the type of an axis the machine does not shape
M593_AXES = "XY"


class ShaperState:
    """The shapers of x, y and z as the program has set them so far: each axis's type, frequency (0: off) and
    damping, from the machine's `input_shaper` at the start."""

    def __init__(self, machine):
        configured = getattr(machine, "input_shaper", None)
        axes = {} if configured is None else configured.axes
        self.type = {a: axes[a].type if a in axes else MARLIN_SHAPER for a in SHAPED_AXES}
        self.freq = {a: axes[a].freq if a in axes else 0.0 for a in SHAPED_AXES}
        self.damping = {a: axes[a].damping if a in axes else DEFAULT_SHAPER_DAMPING for a in SHAPED_AXES}
        self.typed = set(axes)  # the axes whose type the machine gives
        self.noted = False

    def specs(self) -> tuple[ShaperSpec | None, ...]:
        return tuple((self.type[a], self.freq[a], self.damping[a]) if self.freq[a] > 0 else None for a in SHAPED_AXES)


def input_shaping(it, block, params):
    """M593 [X] [Y] F D (see the module): an InputShaping item, unless the line sets neither F nor D (Marlin then
    reports the settings; nothing changes)."""
    state: ShaperState = it.shapers
    axes = [a.lower() for a in M593_AXES if a in params] or ["x", "y"]
    freq, damping = params.get("F"), params.get("D")
    low, high = SHAPER_HZ
    if freq is not None and not (freq == 0.0 or low <= freq <= high):
        it.fail(block, "F", f"'{it.word(block, 'F')}': the shaper frequency must be 0 (off) or from {low:g} to "
                            f"{high:g} Hz")
        return False
    if damping is not None:
        for axis in axes:
            largest = SHAPER_MAX_DAMPING[state.type[axis]]
            if not 0.0 < damping <= largest:  # zeta 0: an undamped frame, which rings for ever
                it.fail(block, "D", f"'{it.word(block, 'D')}': the damping ratio of {axis}'s shaper "
                                    f"({state.type[axis]}) must be > 0 and <= {largest:g}")
                return False
    if freq is None and damping is None:
        return None
    before = state.specs()
    for axis in axes:
        state.freq[axis] = state.freq[axis] if freq is None else freq
        state.damping[axis] = state.damping[axis] if damping is None else damping
    untyped = [a for a in axes if a not in state.typed and state.freq[a] > 0]
    if untyped and not state.noted:
        state.noted = True
        it.notes.append(Diagnostic(it.where(block, it.word_index(block, "M593")),
                                   f"M593 shapes {' and '.join(untyped)} with ZV, Marlin's shaper: the machine has no "
                                   f"input_shaper type for {'them' if len(untyped) > 1 else 'it'} "
                                   f"(machine.input_shaper.{untyped[0]}.type sets one)", "note"))
    it.items.append(InputShaping(state.specs(), before, it.source(block)))
    return None
