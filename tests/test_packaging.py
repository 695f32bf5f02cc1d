"""The distribution installs one import root, ``attopt``, mapped from the top-level folders."""

from __future__ import annotations

import importlib
import pkgutil
import sys
import tomllib
from pathlib import Path

import attopt

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("formulations", "solvers", "experiments")


def _setuptools() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_package_folder_is_listed_under_attopt() -> None:
    config = _setuptools()
    listed = set(config["packages"])
    assert all(name == "attopt" or name.startswith("attopt.") for name in listed)
    on_disk = {"attopt"}
    for folder in FOLDERS:
        for init in (ROOT / folder).rglob("__init__.py"):
            relative = init.parent.relative_to(ROOT).parts
            on_disk.add(".".join(("attopt", *relative)))
    assert listed == on_disk
    assert config["package-dir"] == {"attopt": "attopt"} | {f"attopt.{f}": f for f in FOLDERS}


def test_no_module_is_imported_outside_the_attopt_root() -> None:
    for module in pkgutil.walk_packages(attopt.__path__, "attopt."):
        if module.name.split(".")[-1] == "__main__":
            continue
        importlib.import_module(module.name)
    for package in ("attopt.formulations", "attopt.solvers", "attopt.experiments"):
        parent = importlib.import_module(package)
        for module in pkgutil.walk_packages(parent.__path__, f"{package}."):
            importlib.import_module(module.name)
    stray = sorted(name for name in sys.modules if name.split(".")[0] in FOLDERS)
    assert stray == []
