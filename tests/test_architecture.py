"""The package's layering, stated as a test: a numeric core (data → model → problem → estimators →
evaluation, plus the simulated systems) that never draws or writes files, applications above it
(paper, robot, bench) that do not import each other, one report leaf that writes and draws, and the
CLI on top. No import circles, no ``matplotlib.use``, no module or benchmark script over 400 lines, no
function over 80 lines, no private name imported across modules, and no run, tracker or people labels in
tracked files (history goes to CHANGELOG.md). Where today's code breaks a rule, an explicit allow-list names
the offenders; it may only shrink."""

import ast
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "dualid"
LAYERS = {
    "dualid.errors": 0, "dualid.linalg": 0,
    "dualid.data": 1,
    "dualid.model": 2,
    "dualid.problem": 3, "dualid.identifiability": 3, "dualid.streaming": 3, "dualid.distributed": 3,
    "dualid.metric_guard": 3,
    "dualid.estimators": 4,
    "dualid.evaluation": 5, "dualid.online": 5,
    "dualid.systems": 6,
    "dualid.paper": 7, "dualid.robot": 7, "dualid.bench": 7, "dualid.excite": 7,
    "dualid.report": 8,
    "dualid.cli": 9,
}
CORE = 6  # layers 0..6 are the numeric core
APPLICATIONS = ("dualid.paper", "dualid.robot", "dualid.bench", "dualid.excite")
GUI_OR_CLI = ("matplotlib", "typer", "rich")
WRITERS = ("write_text", "write_bytes", "savefig", "to_parquet", "to_csv", "savez", "savez_compressed", "mkdir",
           "safe_dump", "dump")
MAX_LINES = 400


def _module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in sorted(SRC.rglob("*.py"))}


def _layer_key(module: str) -> str:
    for key in sorted(LAYERS, key=len, reverse=True):
        if module == key or module.startswith(key + "."):
            return key
    raise AssertionError(f"module {module} belongs to no layer; add its package to LAYERS")


def _imports(path: Path) -> list[tuple[str, int]]:
    """(imported module, line) for every import in the file, at any depth (lazy imports count)."""
    tree = ast.parse(path.read_text())
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.module, node.lineno))
            out += [(f"{node.module}.{a.name}", node.lineno) for a in node.names
                    if f"{node.module}.{a.name}" in MODULES]
    return out


def _internal_edges() -> dict[str, set[str]]:
    edges: dict[str, set[str]] = {m: set() for m in MODULES}
    for m, path in MODULES.items():
        for target, _ in _imports(path):
            if target.startswith("dualid") and target in MODULES and target != m:
                edges[m].add(target)
    return edges


def test_every_module_is_in_a_layer():
    for m in MODULES:
        if m != "dualid":
            _layer_key(m)


@pytest.mark.parametrize("module", [m for m in MODULES if m != "dualid"])
def test_imports_follow_the_layers(module):
    key = _layer_key(module)
    layer = LAYERS[key]
    bad = []
    for target, line in _imports(MODULES[module]):
        top = target.split(".")[0]
        if target == "dualid":
            bad.append(f"line {line}: imports the package root (the public API); import the defining module")
        elif target.startswith("dualid."):
            tkey = _layer_key(target)
            if LAYERS[tkey] > layer:
                bad.append(f"line {line}: {target} (layer {LAYERS[tkey]}) is above {key} (layer {layer})")
            elif key in APPLICATIONS and tkey in APPLICATIONS and tkey != key:
                bad.append(f"line {line}: application {key} imports application {tkey}")
        elif layer <= CORE and top in GUI_OR_CLI:
            bad.append(f"line {line}: the numeric core imports {top}")
    assert not bad, f"{module}:\n" + "\n".join(bad)


def test_no_import_circles():
    edges = _internal_edges()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for t in sorted(edges[m]):
            # a package's __init__ re-exporting its own submodules is not a circle
            if m == t.rsplit(".", 1)[0] or t == m.rsplit(".", 1)[0]:
                continue
            if state.get(t) == 1:
                return stack[stack.index(t):] + [t]
            if t not in state and (cycle := visit(t)):
                return cycle
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(edges):
        if m not in state and (cycle := visit(m)):
            pytest.fail("import circle: " + " -> ".join(cycle))


def test_the_core_writes_no_files():
    bad = []
    for m, path in MODULES.items():
        if m == "dualid" or LAYERS[_layer_key(m)] > CORE:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in WRITERS:
                bad.append(f"{m}:{node.lineno} calls .{node.func.attr}()")
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "open":
                modes = [a.value for a in node.args[1:2] if isinstance(a, ast.Constant)]
                modes += [k.value.value for k in node.keywords if k.arg == "mode" and isinstance(k.value, ast.Constant)]
                if any(set(str(x)) & set("wax+") for x in modes):
                    bad.append(f"{m}:{node.lineno} opens a file for writing")
    assert not bad, "\n".join(bad)


def test_nobody_sets_the_matplotlib_backend():
    bad = [f"{m}:{n.lineno}" for m, p in MODULES.items() for n in ast.walk(ast.parse(p.read_text()))
           if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr == "use"
           and isinstance(n.func.value, ast.Name) and n.func.value.id == "matplotlib"]
    assert not bad, f"matplotlib.use called at {bad}"


def test_no_module_is_too_long():
    long = {m: n for m, p in MODULES.items() if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines: {long}"


def test_importing_dualid_keeps_the_users_matplotlib_backend():
    import subprocess
    import sys

    code = ("import matplotlib; matplotlib.use('svg'); import importlib, pkgutil, dualid\n"
            "for m in pkgutil.walk_packages(dualid.__path__, 'dualid.'):\n"
            "    if m.name != 'dualid.cli.__main__': importlib.import_module(m.name)\n"
            "print(matplotlib.get_backend())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "svg"


def test_the_public_api_resolves():
    import dualid

    missing = [n for n in dualid.__all__ if not hasattr(dualid, n)]
    assert not missing and len(set(dualid.__all__)) == len(dualid.__all__)


BUILTIN_ERRORS = {"ValueError", "TypeError", "KeyError", "IndexError", "FileNotFoundError", "FileExistsError",
                  "RuntimeError", "OSError", "PermissionError", "NotImplementedError"}


def test_every_error_raised_on_purpose_is_a_dualid_error():
    bad = []
    for m, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and isinstance(node.exc.func, ast.Name) \
                    and node.exc.func.id in BUILTIN_ERRORS:
                bad.append(f"{m}:{node.lineno} raises {node.exc.func.id}")
    assert not bad, "raise a dualid.errors type instead:\n" + "\n".join(bad)


# --- the repository speaks of the software only ----------------------------------------------------------------

REPO = SRC.parents[1]
# Assembled from pieces so that this file does not match itself.
_RUN_LABELS = "|".join((
    r"sess" r"ion ?[0-9]",           # a run label: "sessionN" / "session N"
    r"iss" r"ue ?#?[0-9]+",          # a tracker item: "issue N" / "issue #N"
    r"help" r"er (session|agent)",
    r"\bthe le" r"ad\b",
    r"other ag" r"ents",
    r"(?-i:DES" r"IGN\.md)",         # not in the repository (case-sensitive: docs may have a lower-case one)
))
RUN_LABEL = re.compile(_RUN_LABELS.encode(), re.IGNORECASE)
HISTORY_FILES = {"CHANGELOG.md"}  # the one place for history
# Not part of the repository when the tree is walked instead of listed by git (named, never skipped silently).
UNTRACKED_DIRS = {".git", "__pycache__", ".pytest_cache", ".mypy_cache", ".hypothesis", ".ruff_cache", "build",
                  "dist", ".venv", "venv"}


def _repository_files() -> list[Path]:
    """Every tracked file (``git ls-files``) in a checkout; outside one, every file of the tree except the
    build and cache folders named in UNTRACKED_DIRS and ``*.egg-info``."""
    import subprocess

    if (REPO / ".git").exists():
        out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
        return [REPO / name for name in out.decode().split("\0") if name]
    return [p for p in REPO.rglob("*") if p.is_file()
            and not any(part in UNTRACKED_DIRS or part.endswith(".egg-info") for part in p.relative_to(REPO).parts)]



def test_no_run_tracker_or_people_labels_outside_the_changelog():
    files = _repository_files()
    assert files, f"no files found under {REPO}"
    bad = []
    for path in files:
        rel = path.relative_to(REPO).as_posix()
        if rel in HISTORY_FILES or not path.exists():  # deleted in the tree: no text
            continue
        for lineno, line in enumerate(path.read_bytes().splitlines(), 1):
            if m := RUN_LABEL.search(line):
                bad.append(f"{rel}:{lineno}: {m.group().decode(errors='replace')!r}")
        rel_name = rel.lower()
        if RUN_LABEL.search(rel_name.encode()) or re.search(r"sess" r"ion", rel_name):
            bad.append(f"{rel}: the file name is a run label")
    assert not bad, "history belongs in CHANGELOG.md; the repository speaks of the software:\n" + "\n".join(bad)


def test_the_label_guard_finds_labels():
    for text in ("sess" "ion 7", "Sess" "ion5", "iss" "ue 11", "iss" "ue #3", "see DES" "IGN.md", "ask the le" "ad",
                 "three other ag" "ents", "another help" "er agent"):
        assert RUN_LABEL.search(text.encode()), text
    for text in ("the lea" "ding column", "an issue with units", "session-free", "docs/des" "ign.md"):
        assert not RUN_LABEL.search(text.encode()), text


# --- sizes of scripts and functions -------------------------------------------------------------------------------

BENCHMARKS = REPO / "benchmarks"
# Benchmark scripts over MAX_LINES today. This list may only shrink: split a script and remove it here.
LONG_BENCHMARKS = {"statistical_quality.py"}
MAX_FUNCTION_LINES = 80
# Functions over MAX_FUNCTION_LINES today (module, qualified name). This list may only shrink: a function that is
# split must be removed from it (the test says so), and no new function may join it.
LONG_FUNCTIONS = {
    ("dualid.data.io", "load_log"),
    ("dualid.estimators.newton.interior_point", "run_interior_point"),
    ("dualid.model.urdf", "identified_urdf"),
}


def _ratchet(found: set, allowed: set, what: str) -> None:
    new, fixed = sorted(found - allowed), sorted(allowed - found)
    assert not new, f"new {what}: {new}"
    assert not fixed, f"no longer {what} (remove them from the allow-list, it only shrinks): {fixed}"


def test_no_benchmark_script_is_too_long():
    scripts = sorted(BENCHMARKS.glob("*.py"))
    assert scripts, f"no benchmark scripts under {BENCHMARKS}"
    _ratchet({p.name for p in scripts if len(p.read_text().splitlines()) > MAX_LINES}, LONG_BENCHMARKS,
             f"benchmark scripts over {MAX_LINES} lines")


def test_every_benchmark_has_a_readme_row_and_no_dated_result_folder():
    """One script per question, listed in benchmarks/README.md; results beside it, older ones in git history."""
    readme = (BENCHMARKS / "README.md").read_text()
    unlisted = sorted(p.name for p in BENCHMARKS.glob("*.py") if f"benchmarks/{p.name}" not in readme)
    assert not unlisted, f"benchmark scripts without a row in benchmarks/README.md: {unlisted}"
    dated = sorted(str(d.relative_to(BENCHMARKS)) for d in BENCHMARKS.rglob("*") if d.is_dir()
                   and (re.fullmatch(r"(?i)session.*|run.?[0-9]+|[0-9a-f]{7,40}|20[0-9]{2}-?[0-9]{2}-?[0-9]{2}.*", d.name)))
    assert not dated, f"result folders named after a run, a commit or a date: {dated}"


def _functions(tree: ast.AST, prefix: str = ""):
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            name = prefix + node.name
            if not isinstance(node, ast.ClassDef):
                yield name, node
            yield from _functions(node, name + ".")


def test_no_function_is_too_long():
    found = {(m, name) for m, path in MODULES.items() for name, node in _functions(ast.parse(path.read_text()))
             if node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES}
    _ratchet(found, LONG_FUNCTIONS, f"functions over {MAX_FUNCTION_LINES} lines")


# --- private names stay in their module ---------------------------------------------------------------------------

# Cross-module imports of underscore names today (importing module, defining module, name). This list may only
# shrink: make the name public (or move the code to its one home) and remove the entry.
PRIVATE_IMPORTS: set[tuple[str, str, str]] = set()


def _private_imports(module: str, path: Path) -> set[tuple[str, str, str]]:
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:  # relative import: resolve against this module's package
            base = package.split(".")[: len(package.split(".")) - node.level + 1]
            source = ".".join(base + ([node.module] if node.module else []))
        else:
            source = node.module or ""
        if not source.startswith("dualid"):
            continue
        for alias in node.names:
            private = alias.name.startswith("_") and not alias.name.startswith("__")
            if private and source != module:
                out.add((module, source, alias.name))
    return out


def test_no_private_name_is_imported_across_modules():
    found = set().union(*(_private_imports(m, p) for m, p in MODULES.items()))
    _ratchet(found, PRIVATE_IMPORTS, "cross-module imports of private names")


HEAVY = ("numpy", "scipy", "pinocchio", "matplotlib", "cvxpy", "mujoco", "pandas", "pydantic", "jinja2")


@pytest.mark.parametrize("code", [
    "import dualid",
    "from dualid.cli import app\ntry:\n    app(['--help'], prog_name='dualid')\nexcept SystemExit:\n    pass",
])
def test_import_and_help_load_no_heavy_library(code):
    """``import dualid`` and ``dualid --help`` import only what they use: the public names resolve on
    first access (module ``__getattr__``) and every command imports its implementation when it runs."""
    import subprocess
    import sys

    probe = code + f"\nimport sys\nprint(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"


def test_a_fit_and_its_report_load_no_plotting_library_filter_or_conic_solver():
    """``dualid fit`` draws its figures as SVG markup (``report.svgplot``) and imports cvxpy, scipy.signal (0.7 s CPU,
    scipy.stats with it), scipy.spatial (floating bases) and MuJoCo only where a fit uses them: its modules load none
    of them, nor matplotlib (0.36 s) or pandas."""
    import subprocess
    import sys

    probe = ("from dualid.robot.config import FitConfig\nfrom dualid.robot.fit import fit_robot\n"
             "from dualid.report.robot import write_fit\nimport sys\n"
             "print(sorted(set(sys.modules) & {'matplotlib', 'cvxpy', 'pandas', 'mujoco', 'scipy.signal', 'scipy.stats', 'scipy.spatial'}))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"


def test_public_names_resolve_to_their_defining_objects():
    import importlib

    import dualid

    for name, module in dualid._LAZY.items():
        assert getattr(dualid, name) is getattr(importlib.import_module(module), name), name
    with pytest.raises(AttributeError):
        dualid.no_such_name  # noqa: B018
