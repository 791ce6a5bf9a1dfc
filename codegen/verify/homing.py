"""Homing in the simulator: each motor's homing steps against what the simulated switches' places imply
(codegen/verify/compare.py puts the switches there: `simulated_switches`)."""

from __future__ import annotations

import numpy as np

from codegen.firmware.homing import homing_steps
from codegen.pipeline.host import HostBuild


def homing_report(host: HostBuild, trace, switches: dict[int, int | None]) -> tuple[dict, list[str]]:
    """Homing steps per motor against what the switch positions imply: per axis that moves it, fast + back
    off + slow approach steps, ending at the switch (a corexy's belts home in x and again in y). A switch at
    None never closes."""
    problems = [trace.homing_fault or "homing failed"] if trace.homing_failed else []  # "homing failed in the ..."
    home = np.asarray(trace.step_phase) == "home"
    expected: dict[int, dict] = {}
    for k, h in enumerate(host.homing):
        switch = switches.get(k)
        towards = None if switch is None else int(switch) * h.direction
        for m, d in zip(h.motors, h.motor_directions):
            mine = expected.setdefault(m, {"steps": 0, "net": 0, "switches": []})
            mine["steps"] += h.max_steps if towards is None else sum(homing_steps(h, abs(towards)))
            mine["net"] += 0 if towards is None else d * towards
            mine["switches"].append(h.switch)
    report = {}
    for m, want in expected.items():
        name = host.kin.motors[m]
        mine = home & (trace.step_motor == m)
        steps, net = int(mine.sum()), int(trace.step_dir[mine].sum())
        report[name] = {"steps": steps, "expected_steps": want["steps"], "net": net, "expected_net": want["net"],
                        "switch": ", ".join(want["switches"])}
        if not trace.homing_failed and (steps != want["steps"] or net != want["net"]):
            problems.append(f"motor {name} homed in {steps} steps ending {net} from its start; its switches "
                            f"({report[name]['switch']}) imply {want['steps']} steps ending {want['net']}")
    return report, problems
