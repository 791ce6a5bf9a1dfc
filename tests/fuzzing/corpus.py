"""The fuzzer's seeds: the G-code files of tests/data/gcode/** (and the example jobs' inline G-code), the
machines of the example jobs (with and without ranges, on both targets) and the job files themselves."""

from __future__ import annotations

import copy
import random
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import yaml

from codegen.errors import JobError
from codegen.job import load_job

ROOT = Path(__file__).resolve().parent.parent.parent
GCODE_DIR = ROOT / "tests" / "data" / "gcode"
JOB_GLOBS = ("examples/*.yaml", "examples/*/*.yaml", "tests/data/**/*.yaml")
# Known failures, no seeds (a run's inputs stay the same): the fuzzer's (tests/data/fuzz-open) and the property
# generator's (tests/data/jobs/open)
OPEN_FINDINGS = (("fuzz-open",), ("jobs", "open"))
WHOLE_FILE_LINES = 200  # a longer file (the slicers' prints) is cut to a window of MIN..MAX_WINDOW lines
MIN_WINDOW, MAX_WINDOW = 20, 200
PROGRAM_KEYS = ("start", "feed", "travel_feed", "s_max", "dialect")  # kept with a machine: a delta starts homed


@dataclass(frozen=True)
class GcodeSeed:
    name: str  # a path under tests/data/gcode, or "<job>:inline"
    lines: tuple[str, ...]


@dataclass(frozen=True)
class MachineSeed:
    name: str  # the job file it came from
    job: dict  # the job without its program's shapes or G-code: name, target, board, machine, program extras

    @property
    def has_extruder(self) -> bool:
        return "e" in self.job["machine"].get("steppers", {})


@dataclass(frozen=True)
class JobSeed:
    path: Path
    text: str


def _relative(path: Path) -> str:
    return str(path.relative_to(ROOT))


@lru_cache(maxsize=None)
def job_seeds() -> tuple[JobSeed, ...]:
    paths = sorted({p for pattern in JOB_GLOBS for p in ROOT.glob(pattern) if not _open(p.relative_to(ROOT).parts)})
    return tuple(JobSeed(p, p.read_text(encoding="utf-8")) for p in paths)


def _open(parts: tuple[str, ...]) -> bool:
    """Whether a file lies in a folder of known failures (OPEN_FINDINGS)."""
    return any(parts[k:k + len(folder)] == folder for folder in OPEN_FINDINGS for k in range(len(parts)))


def _parsed(seed: JobSeed) -> dict | None:
    try:
        data = yaml.safe_load(seed.text)
    except yaml.YAMLError:  # tests/data/jobs/bad_yaml.yaml
        return None
    return data if isinstance(data, dict) else None


@lru_cache(maxsize=None)
def gcode_seeds() -> tuple[GcodeSeed, ...]:
    files = sorted(GCODE_DIR.rglob("*.gcode"))
    seeds = [GcodeSeed(str(p.relative_to(GCODE_DIR)), tuple(p.read_text(encoding="utf-8").splitlines()))
             for p in files]
    for seed in job_seeds():
        program = (_parsed(seed) or {}).get("program")
        gcode = program.get("gcode") if isinstance(program, dict) else None
        if isinstance(gcode, str) and "\n" in gcode:
            seeds.append(GcodeSeed(f"{_relative(seed.path)}:inline", tuple(gcode.splitlines())))
    return tuple(seeds)


def _loads(seed: JobSeed) -> bool:
    try:
        load_job(seed.path, program_required=False)
    except JobError:  # tests/data/jobs/three_mistakes.yaml and others: their machines are wrong on purpose
        return False
    return True


@lru_cache(maxsize=None)
def machine_seeds() -> tuple[MachineSeed, ...]:
    """The machines of the job files that load."""
    seeds = []
    for seed in job_seeds():
        data = _parsed(seed) if _loads(seed) else None
        machine = data.get("machine") if data else None
        if not isinstance(machine, dict) or not isinstance(machine.get("steppers"), dict):
            continue
        program = data.get("program") if isinstance(data.get("program"), dict) else {}
        job = {key: data[key] for key in ("target", "board") if key in data}
        job["machine"] = machine
        job["program"] = {key: program[key] for key in PROGRAM_KEYS if key in program}
        seeds.append(MachineSeed(_relative(seed.path), job))
    return tuple(seeds)


def excerpt(lines: tuple[str, ...], rng: random.Random) -> list[str]:
    """The whole file, or a window of 20-200 lines of a longer one."""
    if len(lines) <= WHOLE_FILE_LINES:
        return list(lines)
    size = rng.randint(MIN_WINDOW, MAX_WINDOW)
    start = rng.randrange(len(lines) - size)
    return list(lines[start:start + size])


def gcode_for_path(job_path: Path, relative: str) -> tuple[str, ...] | None:
    """The lines of the G-code file a job names (relative to the job), or None where it is not a file."""
    path = (job_path.parent / relative).resolve()
    return tuple(path.read_text(encoding="utf-8").splitlines()) if path.is_file() else None


def varied_machine(seed: MachineSeed, rng: random.Random) -> dict:
    """A copy of a seed's job header: sometimes without ranges, sometimes on the other target."""
    job = copy.deepcopy(seed.job)
    if rng.random() < 0.3:
        for stepper in job["machine"]["steppers"].values():
            if isinstance(stepper, dict):
                stepper.pop("range", None)
    if rng.random() < 0.3:
        job["target"] = rng.choice(("avr", "mcs51"))
        job.pop("board", None)  # a board belongs to one target
    return job
