"""verify --trace's file: one row per simulated step pulse, time_s,motor,dir,phase (CLI.md), written as the pulses
come (a chapter at a time in bounded memory: codegen/verify/bounded.py; the whole run at once otherwise)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

ROWS_AT_ONCE = 1 << 16


class StepsCsv:
    """The file, open for rows: `write` pulses in time order, then `close`."""

    def __init__(self, path: Path, motor_names: tuple[str, ...], f_cpu: int):
        self.names = np.asarray(motor_names, dtype=object)
        self.f_cpu = f_cpu
        self.out = Path(path).open("w", encoding="utf-8")
        self.out.write("time_s,motor,dir,phase\n")

    def write(self, cycle: np.ndarray, motor: np.ndarray, direction: np.ndarray, phase) -> None:
        """Pulses (simulated cycles, motor index, +1 / -1) of one phase ("home", "run") or a phase each."""
        phases = np.broadcast_to(np.asarray(phase, dtype=object), np.shape(cycle))
        for lo in range(0, len(cycle), ROWS_AT_ONCE):
            rows = slice(lo, lo + ROWS_AT_ONCE)
            columns = zip(np.char.mod("%.9f", cycle[rows] / self.f_cpu), self.names[motor[rows]],
                          direction[rows].tolist(), phases[rows])
            self.out.write("".join(f"{t},{m},{d},{p}\n" for t, m, d, p in columns))

    def close(self) -> None:
        self.out.close()
