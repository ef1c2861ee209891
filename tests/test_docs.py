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


def test_library_example_fits_the_dfki_robot_with_public_names(tmp_path):
    """examples/dfki/fit_dfki.py uses only ``dualid.*`` public names: it fits, writes the URDF and
    validates; the URDF loads in Pinocchio."""
    import runpy

    import pinocchio as pin

    example = runpy.run_path(str(ROOT / "examples" / "dfki" / "fit_dfki.py"))
    validations = example["main"](tmp_path)
    assert set(validations) == {"wls", "dm"}
    for v in validations.values():
        assert (v.mean("tau_rmse") < 0.3).all()
    assert pin.buildModelFromUrdf(str(tmp_path / "dm.urdf")).nq == 2


def test_mypy_sees_the_types_of_a_user_script(tmp_path):
    """The package ships py.typed: mypy checks the example against dualid's annotations (no
    'missing library stubs'), and a type error in a user script is caught."""
    from mypy import api

    example = ROOT / "examples" / "dfki" / "fit_dfki.py"
    out, err, status = api.run(["--no-incremental", "--cache-dir", str(tmp_path / "cache"), str(example)])
    assert status == 0, out + err
    bad = tmp_path / "bad.py"
    bad.write_text("import dualid\n\nproblem: int = dualid.build_problem\n")
    out, _, status = api.run(["--no-incremental", "--cache-dir", str(tmp_path / "cache"), str(bad)])
    assert status == 1 and "Incompatible types in assignment" in out, out
