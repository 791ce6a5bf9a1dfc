"""Where the data folders (templates/, targets/) are, installed or in a source checkout."""

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def data_dir(name: str) -> Path:
    """`templates` or `targets`: inside the installed package, else at the top of the source tree."""
    installed = _PACKAGE / name
    if installed.is_dir():
        return installed
    return _PACKAGE.parent / name


def templates_dir() -> Path:
    return data_dir("templates")


def targets_dir() -> Path:
    return data_dir("targets")
