"""The house rules a maintainer relies on, checked on the source of ``reglib/`` and ``service/``.

Module size, parameter counts, private names crossing package borders, dispatch by strings and
option declarations (issue 26's "done when"), so that the rules stay true.
"""
from __future__ import annotations

import ast
import dataclasses
import importlib
import pkgutil
from pathlib import Path

import pytest

import reglib
from reglib.options import option_specs

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted(p for top in ("reglib", "service") for p in (ROOT / top).rglob("*.py"))
MAX_LINES = 600
MAX_PARAMETERS = 10


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def _package_of(path: Path) -> tuple[str, ...]:
    """The dotted package a module belongs to, as a tuple ("reglib", "robust")."""
    return path.relative_to(ROOT).parent.parts


def _imported(path: Path, node: ast.ImportFrom) -> tuple[tuple[str, ...], str]:
    """(package parts, module name) of the module named by a ``from X import ...``."""
    if node.level:
        base = list(_package_of(path))
        if node.level > 1:
            base = base[: len(base) - (node.level - 1)]
        parts = base + (node.module.split(".") if node.module else [])
    else:
        parts = (node.module or "").split(".")
    return tuple(parts[:-1]), parts[-1] if parts else ""


def test_the_dense_stage_is_a_package() -> None:
    assert (ROOT / "reglib" / "dense" / "__init__.py").is_file()


def test_no_library_module_is_over_600_lines() -> None:
    over = {str(p.relative_to(ROOT)): n for p in SOURCES if _package_of(p)[0] == "reglib"
            for n in [len(p.read_text().splitlines())] if n > MAX_LINES}
    assert not over, over


def test_no_function_takes_more_than_10_parameters() -> None:
    over = []
    for path in SOURCES:
        for node in ast.walk(_tree(path)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = node.args
                names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
                names = [n for n in names if n not in ("self", "cls")]
                if len(names) > MAX_PARAMETERS:
                    over.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({len(names)})")
    assert not over, over


def test_registration_dispatches_through_imported_functions() -> None:
    for path in (ROOT / "reglib" / "registration").rglob("*.py"):
        text = path.read_text()
        assert "import_module" not in text and "__import__" not in text, path.name


def test_no_private_name_crosses_a_package_border() -> None:
    found = []
    for path in SOURCES:
        here = _package_of(path)
        for node in ast.walk(_tree(path)):
            if not isinstance(node, ast.ImportFrom) or node.module == "__future__":
                continue
            package, module = _imported(path, node)
            if here[:len(package)] == package:
                continue  # within one package (and its private subpackages), private helpers are shared freely
            top_level_helper = package in (("reglib",), ("service",))
            if module.startswith("_") and not top_level_helper:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno} imports the private module "
                             f"{'.'.join(package)}.{module}")
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {alias.name} from "
                                 f"{'.'.join(package + (module,))}")
    assert not found, found


def _options_classes() -> list[type]:
    classes = {}
    for info in pkgutil.walk_packages(reglib.__path__, "reglib."):
        if info.name.startswith(("reglib.commands", "reglib.cli")):
            continue
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if name.endswith("Options") and isinstance(value, type) and dataclasses.is_dataclass(value):
                classes[f"{value.__module__}.{value.__qualname__}"] = value
    return [classes[k] for k in sorted(classes)]


@pytest.mark.parametrize("cls", _options_classes(), ids=lambda c: c.__name__)
def test_every_options_field_is_declared(cls: type) -> None:
    specs = option_specs(cls)
    assert [s.name for s in specs] == [f.name for f in dataclasses.fields(cls)]
    instance = cls()
    for spec in specs:  # each default passes its own declaration
        assert spec.check(getattr(instance, spec.name)) == getattr(instance, spec.name) or spec.kind == "json"
