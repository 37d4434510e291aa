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
    for name in ("register", "register_many", "read_point_cloud", "write_point_cloud", "fit", "load_model", "mesh_model", "read_mesh"):
        stub_doc = ast.get_docstring(functions[name])
        assert inspect.getdoc(getattr(sdfreg, name)) == stub_doc, name
