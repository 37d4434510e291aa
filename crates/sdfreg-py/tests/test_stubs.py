"""The hand-written stubs agree with the compiled module."""

from __future__ import annotations

import ast
import inspect
import subprocess
import sys
from pathlib import Path

import sdfreg

STUB = Path(sdfreg.__file__).with_name("_sdfreg.pyi")


def test_stubs_match_the_module() -> None:
    """The hand-written .pyi agrees with the compiled module (names, signatures, defaults)."""
    run = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "sdfreg"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stdout + run.stderr


def test_docstrings_match_the_stubs() -> None:
    """help() shows the runtime docstrings, editors the stub's: they must say the same."""
    tree = ast.parse(STUB.read_text(encoding="utf-8"))
    functions = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
    for name in ("register", "register_many", "evaluate_registration", "read_point_cloud", "write_point_cloud", "fit", "load_model", "mesh_model", "read_mesh", "read_poses"):
        stub_doc = ast.get_docstring(functions[name])
        assert inspect.getdoc(getattr(sdfreg, name)) == stub_doc, name


def test_stub_keywords_are_the_bindings() -> None:
    """The stubs declare each settings keyword once (TypedDicts, combined per function); the
    functions that take it are those of the binding's one table (``KEYWORDS``)."""
    tree = ast.parse(STUB.read_text(encoding="utf-8"))
    classes = {n.name: n for n in tree.body if isinstance(n, ast.ClassDef)}

    def keys(name: str) -> set[str]:
        node = classes[name]
        own = {s.target.id for s in node.body if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)}
        for base in node.bases:
            if isinstance(base, ast.Name) and base.id in classes:
                own |= keys(base.id)
        return own

    declared = [
        s.target.id
        for c in classes.values()
        if c.name.endswith(("Keyword", "Keywords"))
        for s in c.body
        if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)
    ]
    assert len(declared) == len(set(declared)), sorted(declared)
    binding = sdfreg._sdfreg._settings_keywords()
    callers = {
        "register": "_RegisterKeywords",
        "register_many": "_ManyKeywords",
        "track": "_TrackKeywords",
        "fit": "_FitKeywords",
        "align": "_AlignKeywords",
    }
    for caller, stub_class in callers.items():
        expected = {name for name, takers in binding.items() if caller in takers}
        assert keys(stub_class) == expected, caller
