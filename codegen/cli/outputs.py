"""A build's folder holds a whole build or none of one.

A build that fails (bad input, exit 2; a failed build or a job that does not fit, exit 1; Ctrl-C) takes away the
files an earlier build left in its folder: the image, its report and the sources that report lists. No older
firmware.hex is left beside a failed job's messages, where it could be flashed by mistake.
"""

from __future__ import annotations

import json
import re
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from codegen.errors import BuildError, JobError

IMAGE_FILES = ("firmware.hex", "firmware.elf", "report.json")
# the job's top-level `name:` read without YAML, for a job file too broken to load (an alias bomb stays unread)
_NAME_LINE = re.compile(r"^name:[ \t]*(['\"]?)([^'\"#\r\n]*?)\1[ \t]*(?:#.*)?$", re.MULTILINE)


def flash_dir(name: str, out: str | None) -> Path:
    return Path(out) if out else Path("build") / name


def stream_dir(name: str, out: str | None) -> Path:
    """The streaming firmware's folder: beside the job's flash image, never over it."""
    return Path(out) if out else Path("build") / name / "stream"


def job_name_guess(job_path: Path) -> str:
    """The name a job file gives itself, or its stem (the loader's default), without loading it."""
    try:
        head = job_path.read_bytes()[:1 << 20].decode("utf-8", errors="replace")
    except OSError:
        return job_path.stem
    found = _NAME_LINE.search(head)
    name = found.group(2).strip() if found else ""
    return name if name and not set(name) & set("/\\") and name not in (".", "..") else job_path.stem


def clear_build(folder: Path) -> None:
    """Remove what a build writes into `folder`; other files there are the user's and stay."""
    names = set(IMAGE_FILES)
    try:
        listed = json.loads((folder / "report.json").read_text(encoding="utf-8")).get("sources", [])
        names |= {name for name in listed if isinstance(name, str) and Path(name).name == name}
    except (OSError, ValueError, AttributeError):
        pass
    for name in names:
        try:
            (folder / name).unlink(missing_ok=True)
        except OSError:  # a folder where a file was, or no permission: not a file this build left
            pass


@contextmanager
def whole_or_none(folder_of) -> Iterator[None]:
    """Run a build; if it fails, clear the folder `folder_of()` names before the error goes on."""
    try:
        yield
    except (JobError, BuildError, KeyboardInterrupt):
        clear_build(folder_of())
        raise
