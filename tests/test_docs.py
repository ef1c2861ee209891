"""The Python examples in README.md and docs/ run as written."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"```python\n(.*?)```", re.S)
EXAMPLES = [(path.name, i, code) for path in PAGES for i, code in enumerate(BLOCK.findall(path.read_text()))]


@pytest.mark.parametrize("name,index,code", EXAMPLES, ids=[f"{n}#{i}" for n, i, _ in EXAMPLES])
def test_docs_example_runs(name, index, code, capsys):
    exec(compile(code, f"{name}#{index}", "exec"), {"__name__": "__docs__"})
