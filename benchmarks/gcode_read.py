"""How fast the G-code front end reads and interprets a sliced print: the PrusaSlicer Benchy (89,383 lines).

Times, best of --repeat runs: reading alone (text -> words, codes.py/reader.py), and reading + interpreting
into the Toolpath (what `toolpath_from_gcode` does, file load included). The budget is well under 1.5 s.

    python benchmarks/gcode_read.py [--file tests/data/gcode/slicer/benchy-prusaslicer.gcode] [--repeat 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from codegen.errors import SourceRef  # noqa: E402
from codegen.gcode import toolpath_from_gcode  # noqa: E402
from codegen.gcode.reader import Origin, read  # noqa: E402

BENCHY = ROOT / "tests" / "data" / "gcode" / "slicer" / "benchy-prusaslicer.gcode"


def printer_job(path: Path) -> SimpleNamespace:
    """A cartesian printer (x, y, z, e) whose program is the file."""
    return SimpleNamespace(
        machine=SimpleNamespace(motor_names=("x", "y", "z", "e"), kinematics="cartesian"),
        program=SimpleNamespace(start=(0, 0), feed=1200, travel_feed=None, gcode=path.name,
                                gcode_source=SourceRef(str(path.parent / "job.yaml"), 1, 1)),
        path=path.parent / "job.yaml")


def best(run, repeat: int) -> tuple[float, object]:
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = run()
        times.append(time.perf_counter() - start)
    return min(times), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--file", type=Path, default=BENCHY)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    path = args.file.resolve()
    text = path.read_text(encoding="utf-8", errors="surrogateescape")
    lines = text.count("\n")
    read_s, blocks = best(lambda: sum(1 for _ in read(text, Origin(str(path)))), args.repeat)
    job = printer_job(path)
    total_s, (toolpath, warnings) = best(lambda: toolpath_from_gcode(job), args.repeat)
    kinds = Counter(type(item).__name__ for item in toolpath.items)
    print(f"{path.name}: {lines} lines, {blocks} blocks, {len(toolpath.items)} items "
          f"({', '.join(f'{n} {k}' for k, n in kinds.most_common())}), {len(warnings)} warnings")
    print(f"read:              {read_s * 1e3:7.1f} ms  ({read_s / lines * 1e6:.2f} us/line)")
    print(f"read + interpret:  {total_s * 1e3:7.1f} ms  ({total_s / lines * 1e6:.2f} us/line)  "
          f"[budget 1500 ms]")


if __name__ == "__main__":
    main()
