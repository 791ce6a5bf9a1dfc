"""Small C helpers for the loops numpy cannot vectorise, compiled at first use with the system's gcc into the
user's cache (like the simavr harness) and loaded with ctypes. Each has a pure-Python version of the same
algorithm that gives the same results (the tests compare them); without gcc that version runs, slowly.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path

import numpy as np

SOURCE_DIR = Path(__file__).resolve().parent
BUILD = ("gcc", "-O2", "-std=c99", "-shared", "-fPIC")
LIBS = ("-lm",)


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "printer-codegen"


def pointer(array: np.ndarray | None):
    """A C pointer to a contiguous array's data, which it keeps alive (None: a null pointer)."""
    return None if array is None else array.ctypes.data_as(ctypes.c_void_p)


def contiguous(dtype, *arrays) -> list[np.ndarray]:
    """The arrays as C sees them: contiguous, of `dtype`."""
    return [np.ascontiguousarray(a, dtype=dtype) for a in arrays]


@lru_cache(maxsize=None)
def library(name: str) -> ctypes.CDLL | None:
    """codegen/native/<name>.c as a loaded shared library, keyed by a hash of its source and build command;
    None when it cannot be built (no gcc) or PRINTER_CODEGEN_PURE_PYTHON is set."""
    if os.environ.get("PRINTER_CODEGEN_PURE_PYTHON"):
        return None
    source = SOURCE_DIR / f"{name}.c"
    key = hashlib.sha256(source.read_bytes() + " ".join(BUILD + LIBS).encode()).hexdigest()[:16]
    built = _cache_dir() / f"{name}-{key}.so"
    if not built.is_file():
        built.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=built.name + ".", dir=built.parent)
        os.close(fd)
        try:
            done = subprocess.run([*BUILD, str(source), *LIBS, "-o", tmp], capture_output=True, text=True)
        except FileNotFoundError:
            done = None
        if done is None or done.returncode != 0:
            os.unlink(tmp)
            return None
        os.replace(tmp, built)  # atomic: a parallel build leaves one whole library
    return ctypes.CDLL(str(built))
