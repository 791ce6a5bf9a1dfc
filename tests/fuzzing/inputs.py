"""The fuzzer's inputs: input k of seed s is made from random.Random(f"{s}:{k}") alone, so a run is the same inputs
in the same order whatever the workers do. An input is a job file and, where it has one, the G-code file it names
(`program.gcode: input.gcode`, beside it)."""

from __future__ import annotations

import copy
import random
from dataclasses import dataclass, replace
from pathlib import Path

import yaml

from tests.fuzzing import corpus
from tests.fuzzing.gcode_mutations import mutate_gcode
from tests.fuzzing.job_mutations import dump, mutate_text, mutate_tree

JOB_NAME, GCODE_NAME = "job.yaml", "input.gcode"
GCODE_SHARE = 0.6  # of the inputs: mutated G-code under a seed machine; the rest mutated job files


@dataclass(frozen=True)
class FuzzInput:
    job: bytes
    gcode: bytes | None = None
    origin: str = ""  # the seeds and mutations it was made from

    @property
    def size(self) -> int:
        return len(self.job) + len(self.gcode or b"")

    def with_part(self, part: str, data: bytes) -> FuzzInput:
        return replace(self, **{part: data})

    def write(self, folder: Path) -> Path:
        """The job file (and its G-code) written into `folder`; the job's path."""
        folder.mkdir(parents=True, exist_ok=True)
        (folder / JOB_NAME).write_bytes(self.job)
        if self.gcode is not None:
            (folder / GCODE_NAME).write_bytes(self.gcode)
        return folder / JOB_NAME


def _gcode_input(rng: random.Random) -> FuzzInput:
    seed = rng.choice(corpus.gcode_seeds())
    machines = corpus.machine_seeds()
    if seed.name.startswith("slicer/"):  # a printer's G-code wants a machine with an extruder
        machines = tuple(m for m in machines if m.has_extruder) or machines
    machine = rng.choice(machines)
    job = corpus.varied_machine(machine, rng)
    job["program"]["gcode"] = GCODE_NAME
    gcode, applied = mutate_gcode(corpus.excerpt(seed.lines, rng), rng)
    origin = f"gcode {seed.name} on {machine.name}: {', '.join(applied)}"
    return FuzzInput(dump(job).encode("utf-8"), gcode, origin)


def _program_gcode(data: dict, seed: corpus.JobSeed, rng: random.Random) -> bytes | None:
    """A G-code file the job names becomes input.gcode, an excerpt of it (the slicers' files are long)."""
    program = data.get("program")
    gcode = program.get("gcode") if isinstance(program, dict) else None
    if not isinstance(gcode, str) or "\n" in gcode:
        return None
    lines = corpus.gcode_for_path(seed.path, gcode)
    if lines is None:
        return None
    program["gcode"] = GCODE_NAME
    return ("\n".join(corpus.excerpt(lines, rng)) + "\n").encode("utf-8")


def _job_input(rng: random.Random) -> FuzzInput:
    seed = rng.choice(corpus.job_seeds())
    try:
        data = yaml.safe_load(seed.text)
    except yaml.YAMLError:
        data = None
    name = seed.path.relative_to(corpus.ROOT)
    if not isinstance(data, dict):  # a seed that is bad YAML already: its text mutated
        job, applied = mutate_text(seed.text, rng)
        return FuzzInput(job, None, f"job {name}: {', '.join(applied)}")
    data = copy.deepcopy(data)
    gcode = _program_gcode(data, seed, rng)
    applied = [mutate_tree(data, rng) for _ in range(rng.choice((0, 1, 1, 2, 3)))]
    try:
        text = dump(data)
    except RecursionError:  # nested values inside nested values, too deep for PyYAML's writer
        text, applied = seed.text, []
    if not applied or rng.random() < 0.4:
        job, more = mutate_text(text, rng)
        applied += more
    else:
        job = text.encode("utf-8")
    return FuzzInput(job, gcode, f"job {name}: {', '.join(applied)}")


def make_input(seed: int, index: int) -> FuzzInput:
    rng = random.Random(f"{seed}:{index}")
    return _gcode_input(rng) if rng.random() < GCODE_SHARE else _job_input(rng)
