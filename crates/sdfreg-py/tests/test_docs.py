"""The guide's examples run: every ```python block of docs/*.md and README.md, each page's blocks
in order in one namespace, in a folder holding the files they read (``source.ply`` and
``target.ply``, a pair with a known answer); the `sdfreg` lines of the pages' first-steps
shell blocks through the CLI (SDFREG_CLI). A renamed function or keyword fails here, naming the
page and the block."""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest

import sdfreg
from conftest import paper_pair, pose_errors

ROOT = Path(__file__).resolve().parents[3]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# Pages whose shell blocks are first steps on the example files (the others' shell blocks run
# benchmarks or show placeholders in capitals; their flags are checked by the CLI's tests).
RUN_SHELL = {"README.md", "getting-started.md", "models.md"}
FENCE = re.compile(r"^( *)```(\w*)[^\n]*\n(.*?)^\1```", re.S | re.M)


def blocks(page: Path, language: str) -> list[str]:
    text = page.read_text(encoding="utf-8")
    return [textwrap.dedent(m.group(3)) for m in FENCE.finditer(text) if m.group(2) == language]


def cli() -> str:
    path = os.environ.get("SDFREG_CLI")
    if not path:
        pytest.skip("SDFREG_CLI is not set (the path of the sdfreg binary)")
    return path


@pytest.fixture()
def files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> np.ndarray:
    source, target, truth = paper_pair(21)
    sdfreg.write_point_cloud(tmp_path / "source.ply", source)
    sdfreg.write_point_cloud(tmp_path / "target.ply", target)
    monkeypatch.chdir(tmp_path)
    return truth


def test_every_page_with_code_is_found() -> None:
    names = {p.name for p in PAGES if blocks(p, "python")}
    assert {"README.md", "getting-started.md", "python.md", "models.md", "batch.md"} <= names, names


@pytest.mark.parametrize("page", [p for p in PAGES if blocks(p, "python")], ids=lambda p: p.name)
def test_python_examples_run(page: Path, files: np.ndarray) -> None:
    namespace: dict = {"__name__": "__docs__"}
    for k, code in enumerate(blocks(page, "python")):
        if "import ray" in code and importlib.util.find_spec("ray") is None:
            continue  # Ray does not install everywhere (scripts/python-env says so)
        try:
            exec(compile(code, f"{page.name}, python block {k + 1}", "exec"), namespace)
        except Exception as e:  # the page and the block, then the error
            raise AssertionError(f"{page.relative_to(ROOT)}: python block {k + 1} failed: {e!r}") from e
        finally:
            if "import ray" in code:
                import ray

                ray.shutdown()
    # Where a page registers the example pair, the answer is right.
    result = namespace.get("result")
    if isinstance(result, sdfreg.Registration):
        rot, trans = pose_errors(result.transformation, files)
        assert rot < 1.0 and trans < 0.01, (page.name, rot, trans)


@pytest.mark.parametrize("page", [p for p in PAGES if p.name in RUN_SHELL], ids=lambda p: p.name)
def test_first_step_commands_run(page: Path, files: np.ndarray) -> None:
    lines = [
        line.split("#")[0].strip()
        for code in blocks(page, "sh")
        for line in code.splitlines()
        if line.startswith("sdfreg ")
    ]
    assert lines, f"{page.name}: no sdfreg command"
    for line in lines:
        args = shlex.split(line)[1:]
        out = subprocess.run([cli(), *args], capture_output=True, text=True)
        assert out.returncode == 0, f"{page.relative_to(ROOT)}: `{line}` failed: {out.stderr}"
    if Path("result.json").exists():
        import json

        m = np.array(json.loads(Path("result.json").read_text())["transformation"])
        rot, trans = pose_errors(m, files)
        assert rot < 1.0 and trans < 0.01, (page.name, rot, trans)
