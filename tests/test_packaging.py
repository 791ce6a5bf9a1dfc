"""The installed package carries every file the toolchain reads at run time: the README's first command installs
it non-editable, so a file left out of package-data breaks `verify` for a new user (the simavr plant's header
once did)."""

import fnmatch
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_non_python_file_of_a_package_folder_is_package_data():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    data = config["package-data"]
    missing = []
    for package in config["packages"]:
        folder = ROOT / Path(*package.split("."))
        if not folder.is_dir() or package in ("codegen.templates", "codegen.targets"):
            continue  # mapped from the repository's top (package-dir), "**/*" and "*.yaml"
        for path in folder.iterdir():
            if path.is_file() and path.suffix not in (".py", ".pyc") and not any(
                    fnmatch.fnmatch(path.name, pattern) for pattern in data.get(package, [])):
                missing.append(str(path.relative_to(ROOT)))
    assert missing == []


def test_every_package_folder_is_listed():
    """A subpackage left out of `packages` is missing from the non-editable install (codegen.job.schema once was:
    the README's first command failed with ModuleNotFoundError)."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(init.parent.relative_to(ROOT).parts) for init in (ROOT / "codegen").rglob("__init__.py")}
    assert found - listed == set()
