"""The Python examples in docs/ run as written."""

import re
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"
BLOCK = re.compile(r"```python\n(.*?)```", re.S)
EXAMPLES = [(path.name, i, code) for path in sorted(DOCS.glob("*.md")) for i, code in enumerate(BLOCK.findall(path.read_text()))]


@pytest.mark.parametrize("name,index,code", EXAMPLES, ids=[f"{n}#{i}" for n, i, _ in EXAMPLES])
def test_docs_example_runs(name, index, code, capsys):
    exec(compile(code, f"{name}#{index}", "exec"), {"__name__": "__docs__"})
