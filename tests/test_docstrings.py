"""Every public name of the ``attopt`` facade has an example in its docstring, and every
docstring example in the package runs and prints what it says (doctest)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import attopt

ROOTS = ("attopt", "attopt.formulations", "attopt.solvers", "attopt.experiments")


def _modules() -> list[str]:
    names = ["attopt"]
    for root in ROOTS[1:]:
        package = importlib.import_module(root)
        names += [root] + [m.name for m in pkgutil.walk_packages(package.__path__, f"{root}.")]
    return names


def _documented(name: str) -> bool:
    value = getattr(attopt, name)
    return callable(value) and not (isinstance(value, type) and issubclass(value, BaseException))


@pytest.mark.parametrize("name", [n for n in attopt.__all__ if _documented(n)])
def test_every_public_name_has_an_example(name: str) -> None:
    assert ">>>" in (getattr(attopt, name).__doc__ or ""), f"attopt.{name} has no example"


@pytest.mark.parametrize("module", _modules())
def test_docstring_examples_run(module: str) -> None:
    result = doctest.testmod(
        importlib.import_module(module),
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
        report=False,
    )
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {module}"
