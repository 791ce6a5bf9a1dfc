"""M3's power against the program's own S (codegen/verify/laser.py steady_power_problems): the tables' power
agrees with it in every example cut, and power scaled by 0.95 on the way into the tables is named."""

from __future__ import annotations

import numpy as np

from codegen.tables.laser import COUNTS, played_counts
from codegen.verify.laser import steady_power_problems


def test_the_tables_power_is_the_programs_s_and_a_scaled_one_is_named(planned_example):
    host = planned_example("laser/power.yaml")  # M3 and M4 cuts
    records = played_counts(host.schedule)
    events = np.arange(len(records))
    played = records & COUNTS
    assert steady_power_problems(host, events, played, records, 128) == []
    scaled = np.round(played * 0.95).astype(np.int64)
    [problem] = steady_power_problems(host, events, scaled, records, 128)
    assert problem.startswith("laser: at simulated event ") and "PWM counts where the program's S gives" in problem
    k = int(problem.split("event ")[1].split(" ")[0])
    assert scaled[k] != played[k] and f"gives {played[k]} of {host.laser.top}" in problem
