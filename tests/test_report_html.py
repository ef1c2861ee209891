"""The fit/validation reports: one value rendered as Markdown and as one self-contained HTML file.

End to end on the DFKI example (``dualid fit --config examples/dfki/fit.yaml``, two methods to keep it
short), and unit checks of the figure rules: a legend per joint with that joint's RMSE (the old plot
showed only the last joint's, as if overall), axes that follow the measured signal, no "± 0.000".
"""

from __future__ import annotations

import hashlib
import re
import shutil
import subprocess
import sys
from datetime import datetime
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from dualid.cli import app
from dualid.evaluation.validation import RunValidation, Validation
from dualid.report.document import Image, Report, Section, Table, Text, mean_cell
from dualid.report.render import to_html, to_markdown
from dualid.report.signals import axis_limits
from dualid.report.svgplot import ROW, TOP, signal_svg

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "dfki"
runner = CliRunner()

VOID = {"meta", "img", "br", "hr", "link", "input", "source", "col", "area", "base", "wbr"}


class Checker(HTMLParser):
    """Well-formedness (every non-void element closed in order) and self-containment (no external
    src/href, no script, no stylesheet link)."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.external: list[str] = []
        self.images = 0
        self.ids: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag in ("script", "link", "iframe", "object", "embed"):
            self.external.append(f"<{tag}>")
        for key in ("src", "href", "srcset", "data"):
            v = a.get(key)
            if v is not None and not (v.startswith("data:image/png;base64,") or v.startswith("#")):
                self.external.append(f"{tag} {key}={v[:60]}")
        if tag in ("img", "svg"):  # a PNG embedded, or an inline SVG figure
            self.images += 1
        if "id" in a:
            self.ids.append(a["id"])
        if tag not in VOID:
            self.stack.append(tag)

    def handle_startendtag(self, tag, attrs):
        self.handle_starttag(tag, attrs)
        if tag not in VOID:
            self.stack.pop()

    def handle_endtag(self, tag):
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1] if self.stack else 'nothing'}")
            return
        self.stack.pop()

    def handle_data(self, data):
        self.text.append(data)


def check_html(text: str) -> Checker:
    c = Checker()
    c.feed(text)
    c.close()
    assert text.startswith("<!DOCTYPE html>")
    assert not c.errors and not c.stack, (c.errors, c.stack)
    assert not c.external, c.external
    return c


def invoke(args: list[str]):
    """The CLI as a user runs it (sys.argv is what the run metadata records as the command line)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sys, "argv", ["/usr/bin/dualid", *args])
        return runner.invoke(app, args)


ZERO_SPREAD = re.compile(r"± 0(\.0*)?(?![0-9.])")  # "± 0.000", "± 0", not "± 0.00029"


@pytest.fixture(scope="module")
def dfki_fit(tmp_path_factory):
    out = tmp_path_factory.mktemp("dfki") / "fit"
    result = invoke(["fit", "--config", str(EXAMPLE / "fit.yaml"), "--method", "ols", "--method", "dm",
                     "--out", str(out)])
    assert result.exit_code == 0, result.output
    return out


def test_the_dfki_fit_writes_a_self_contained_html_report(dfki_fit):
    html = (dfki_fit / "report.html").read_text()
    c = check_html(html)
    text = " ".join(" ".join(c.text).split())
    # every held-out run plotted (effort and acceleration), each figure embedded
    for run in ("trajectory_04", "trajectory_05"):
        for stem in ("effort", "acceleration"):
            assert f"{stem}_{run}.svg" in c.ids
            svg = (dfki_fit / f"{stem}_{run}.svg").read_text()  # the Markdown's copy: the same markup, standalone
            assert svg.startswith("<svg ") and svg in html and f"![{stem}_{run}.svg]({stem}_{run}.svg)" in \
                (dfki_fit / "report.md").read_text()
    assert c.images == 6  # 2 runs × 2 signals + scores.svg + friction.svg
    # what the fit says physically: friction curves, each link against the URDF, the data's commit
    assert "friction.svg" in c.ids and "Joint friction" in text and "Links against the URDF" in text
    for link in ("Joint1", "Joint2"):
        assert f"<caption>{link}</caption>" in html
    # the commit of the repository holding the data; in an export of the sources (no .git) it says there is none
    in_git = shutil.which("git") and subprocess.run(["git", "-C", str(EXAMPLE), "rev-parse", "HEAD"],
                                                    capture_output=True).returncode == 0
    assert re.search(r"data commit</td><td>[0-9a-f]{40}(-dirty)? \(" if in_git else
                     r"data commit</td><td>\(the input files are in no git repository\)</td>", html)
    # training and held-out scores, per method and reference, per joint
    assert "training τ RMSE [N m], mean ± std over 4 runs" in text
    assert "held-out τ RMSE [N m], mean ± std over 2 runs" in text
    for label in ("ols", "dm", "lab model 2.0", "lab model 2.1"):
        assert f"<td>{label}</td>" in html
    # solver / fallback / guard per method; readable preprocessing (rounded), run metadata
    assert "metric vs URDF" in text and "fallback" in text
    assert "downsample" in text and "cutoff = 40" in text and "39.99999" not in html
    assert not ZERO_SPREAD.search(html) and not ZERO_SPREAD.search((dfki_fit / "report.md").read_text())
    assert "dualid fit --config" in text and "SHA-256" in text


def test_markdown_and_html_show_the_same_tables(dfki_fit):
    md = (dfki_fit / "report.md").read_text()
    html = (dfki_fit / "report.html").read_text()
    rows = [line for line in md.splitlines() if line.startswith("| ") and " ± " in line]
    assert len(rows) > 10
    for line in rows:
        cells = [c.strip() for c in line.strip("|").split(" | ")]
        for cell in cells:
            assert cell.replace("&", "&amp;") in html, cell
    # no table wider than the joints of one group plus the model column (the old one had 3·n + 1 columns)
    widths = {len(line.strip("|").split(" | ")) for line in md.splitlines() if line.startswith("| model |")}
    assert widths == {3}


def test_parameters_yaml_records_the_run(dfki_fit):
    record = yaml.safe_load((dfki_fit / "parameters.yaml").read_text())
    run = record["run"]
    assert run["dualid_version"] and "git_commit" in run
    datetime.strptime(run["time_utc"], "%Y-%m-%dT%H:%M:%SZ")
    assert run["command"].startswith("dualid fit --config")
    roles = {}
    for entry in run["inputs"]:
        roles.setdefault(entry["role"], []).append(Path(entry["path"]).name)
        assert entry["sha256"] == hashlib.sha256(Path(entry["path"]).read_bytes()).hexdigest()
    assert roles["config"] == ["fit.yaml"] and roles["urdf"] == ["pendubot_model_2.1.urdf"]
    assert roles["train"] == [f"trajectory_0{i}.csv" for i in range(4)] and len(roles["test"]) == 2
    assert len(roles["reference"]) == 2
    train = record["methods"]["dm"]["training_scores"]
    assert len(train["runs"]) == 4 and set(train["mean"]["tau_rmse"]) == {"Joint1", "Joint2"}
    assert record["references"]["lab model 2.0"]["training_scores"]["label"] == "lab model 2.0"


def test_validate_writes_the_html_report_with_one_run(dfki_fit, tmp_path):
    out = tmp_path / "val"
    result = invoke(["validate", "--model", str(dfki_fit / "dm.urdf"),
                     "--data", str(EXAMPLE / "data" / "trajectory_05.csv"),
                     "--config", str(EXAMPLE / "fit.yaml"), "--out", str(out)])
    assert result.exit_code == 0, result.output
    html = (out / "report.html").read_text()
    c = check_html(html)
    text = " ".join(" ".join(c.text).split())
    assert "τ RMSE [N m], 1 run" in text and " ± " not in text.split("Signals")[0]
    assert c.images == 2 and "effort_trajectory_05.svg" in c.ids
    record = yaml.safe_load((out / "validation.json").read_text())
    assert record["run"]["command"].startswith("dualid validate")


# --- figures ---------------------------------------------------------------------------------------
def _validation(label: str, tau_pred: np.ndarray, a_pred: np.ndarray | None = None) -> Validation:
    t = np.linspace(0.0, 1.0, 50)
    tau = np.stack([np.sin(2 * np.pi * t), 0.5 * np.cos(2 * np.pi * t)], axis=1)
    a = 10 * tau
    a_pred = a if a_pred is None else a_pred
    rmse = np.sqrt(np.mean((tau_pred - tau) ** 2, axis=0))
    run = RunValidation("run", t, tau, tau_pred, a, a_pred, rmse, np.ones(2),
                        np.sqrt(np.mean((a_pred - a) ** 2, axis=0)), np.ones(2))
    return Validation(label, ("J1", "J2"), (run,))


def _curves(svg: str, key: str) -> dict[str, np.ndarray]:
    """title → y pixels of each polyline in the clipped group ``key`` (s<run><signal><joint> signals, r… residuals)."""
    group = re.search(rf'<g clip-path="url\(#{key}\)">(.*?)</g>', svg).group(1)
    return {title: np.array([float(p.split(",")[1]) for p in points.split()])
            for points, title in re.findall(r'points="([^"]*)"><title>([^<]*)</title>', group)}


def test_each_joint_has_its_own_legend_with_its_rmse():
    # regression: the old plot put one legend under the last panel, so the RMSE it showed per method was
    # the last joint's, read as if overall
    t = np.linspace(0.0, 1.0, 50)
    tau = np.stack([np.sin(2 * np.pi * t), 0.5 * np.cos(2 * np.pi * t)], axis=1)
    vals = {"ols": _validation("ols", tau + [0.1, 0.02]), "dm": _validation("dm", tau + [0.3, 0.04])}
    sf = signal_svg(vals, 0, "tau")
    legends = re.split(r'<text x="\d+" y="\d+">J2</text>', sf.svg)
    assert len(legends) == 2  # the legend of J2 follows J1's
    for j, legend in enumerate(legends):
        entries = re.findall(r'<text class="tick" x="\d+" y="\d+">([^<]*RMSE[^<]*)</text>', legend)
        assert entries == [f"ols: RMSE {[0.1, 0.02][j]:.3g} N m", f"dm: RMSE {[0.3, 0.04][j]:.3g} N m"], entries
        residuals = _curves(sf.svg, f"r0tau{j}")  # ols's residual is the constant offset: a flat line
        assert np.ptp(residuals[entries[0]]) < 1e-9 and np.ptp(_curves(sf.svg, f"s0tau{j}")["measured"]) > 10
    assert not sf.clipped


def test_axes_follow_the_measured_signal_and_the_caption_says_what_is_clipped():
    t = np.linspace(0.0, 1.0, 50)
    tau = np.stack([np.sin(2 * np.pi * t), 0.5 * np.cos(2 * np.pi * t)], axis=1)
    wild = 10 * tau.copy()
    wild[10, 0] = 1e4  # a forward-dynamics blow-up on joint J1
    vals = {"ols": _validation("ols", tau, a_pred=wild)}
    sf = signal_svg(vals, 0, "a")
    measured = _curves(sf.svg, "s0a0")["differentiated (measured q)"]
    assert TOP + 0.04 * (ROW - TOP) < measured.min() and measured.max() < ROW - 0.04 * (ROW - TOP)  # the frame
    assert sf.clipped == ("ols (J1)",)
    assert "clipped" in sf.caption and "ols (J1)" in sf.caption
    # predictions near the measurement widen the axes instead of being clipped
    lo2, hi2 = axis_limits(np.array([0.0, 1.0]), [np.array([-0.3, 1.2])])
    assert lo2 < -0.3 and hi2 > 1.2


def test_one_run_has_no_spread_and_small_spreads_keep_a_digit():
    assert ZERO_SPREAD.search("0.961 ± 0.000 |") and ZERO_SPREAD.search("1 ± 0") and not ZERO_SPREAD.search("± 0.00029")
    assert mean_cell([0.25]) == "0.250"
    assert mean_cell([0.25, 0.27]) == "0.260 ± 0.010"
    assert mean_cell([0.9610, 0.9615]) == "0.961 ± 0.0003"
    assert mean_cell([np.nan]) == "—"


# --- the report value -------------------------------------------------------------------------------
def test_a_new_section_renders_in_both_writers():
    extra = Section("Base parameters", (Text("a < b & c"), Table(("name", "value"), (("m1 + m2", "1.5"),),
                                                                    title="base", note="from QR")))
    report = Report("T", (Section("Empty"), extra, Section("Fig", (Image("f.png", b"\x89PNG", "cap"),))))
    md, html = to_markdown(report), to_html(report)
    assert "## Base parameters" in md and "| m1 + m2 | 1.5 |" in md and "## Empty" not in md
    assert "![f.png](f.png)" in md and "*cap*" in md
    c = check_html(html)
    assert "a &lt; b &amp; c" in html and "<caption>base</caption>" in html and "Empty" not in html
    assert c.images == 1 and re.search(r'src="data:image/png;base64,iVBORw=="', html)
    assert [i.name for i in report.images] == ["f.png"]


def test_the_templates_are_package_data():
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert 'dualid = ["py.typed", "report/templates/*.j2"]' in pyproject and '"jinja2>=' in pyproject
    assert (ROOT / "src" / "dualid" / "report" / "templates" / "report.html.j2").is_file()


def test_score_tables_of_many_joints_are_split():
    from dualid.report.fit_report import score_tables

    coords = tuple(f"j{i}" for i in range(9))
    t = np.linspace(0, 1, 20)
    z = np.zeros((20, 9))
    run = RunValidation("r", t, z, z, z, z, np.arange(9.0), np.ones(9), np.ones(9), np.ones(9))
    tables = score_tables({"ols": Validation("ols", coords, (run,))})
    assert len(tables) == 6  # 3 scores × 2 groups of joints
    assert [len(t.header) for t in tables[:2]] == [8, 3] and tables[0].header[1:] == coords[:7]
    assert tables[1].title == "held-out τ RMSE [N m], 1 run (joints 2/2)"
    assert tables[1].rows == (("ols", "7.000", "8.000"),)


def test_the_svg_names_each_curve_with_its_joint_rmse_and_keeps_the_measurement_in_frame():
    t = np.linspace(0.0, 1.0, 50)
    tau = np.stack([np.sin(2 * np.pi * t), 0.5 * np.cos(2 * np.pi * t)], axis=1)
    wild = tau.copy()
    wild[5, 1] = 1e4
    vals = {"ols": _validation("ols", tau + [0.1, 0.02]), "dm&co": _validation("dm&co", wild)}
    svg = signal_svg(vals, 0, "tau").svg
    check_html(f"<!DOCTYPE html><html><body>{svg}</body></html>")
    assert "<title>ols: RMSE 0.1 N m</title>" in svg and "<title>ols: RMSE 0.02 N m</title>" in svg
    assert "<title>dm&amp;co: RMSE 0 N m</title>" in svg  # labels escaped
    for j in range(2):
        y = _curves(svg, f"s0tau{j}")["measured"]
        assert TOP + ROW * j <= y.min() and y.max() <= ROW * (j + 1)  # the axes follow the measured signal


def _commit_all(path) -> str:
    """Make ``path`` a git repository (if it is not one) with everything in it committed; its HEAD."""
    import subprocess

    git = ["git", "-C", str(path), "-c", "user.name=t", "-c", "user.email=t@t"]
    for args in (["init", "-q"], ["add", "."], ["commit", "-q", "-m", "x"]):
        subprocess.run([*git, *args], check=True)
    return subprocess.run([*git, "rev-parse", "HEAD"], check=True, capture_output=True, text=True).stdout.strip()


def test_the_git_commit_is_dualids_own_or_none(tmp_path):
    from dualid.report.metadata import PACKAGE_DIR, git_commit

    commit = git_commit()
    if (PACKAGE_DIR.parents[1] / ".git").exists():  # run from a checkout (a worktree has a .git file)
        assert re.fullmatch(r"[0-9a-f]{40}(-dirty)?", commit)
    # a package folder inside another project's repository (e.g. its virtual environment) has no commit
    pkg = tmp_path / "project" / ".venv" / "lib" / "dualid"
    pkg.mkdir(parents=True)
    (pkg / "x.py").write_text("")
    _commit_all(tmp_path / "project")
    assert git_commit(pkg) is None
    assert git_commit(tmp_path) is None  # not a repository at all


def test_the_git_commit_is_dirty_only_when_the_package_changed(tmp_path):
    """A benchmark rewriting its result file beside the sources leaves the commit clean; a changed source does not."""
    from dualid.report.metadata import git_commit

    pkg = tmp_path / "src" / "dualid"
    pkg.mkdir(parents=True)
    (pkg / "x.py").write_text("a = 1\n")
    (tmp_path / "result.md").write_text("old\n")
    head = _commit_all(tmp_path)
    (tmp_path / "result.md").write_text("new\n")
    assert git_commit(pkg) == head
    (pkg / "x.py").write_text("a = 2\n")
    assert git_commit(pkg) == head + "-dirty"


def test_floating_base_translations_are_labelled_in_newtons_and_metres():
    from dualid.report.signals import unit_of

    assert [unit_of("tau", c) for c in ("vx", "wz", "Joint1")] == ["N", "N m", "N m"]
    assert [unit_of("a", c) for c in ("vz", "wx", "Joint1")] == ["m/s²", "rad/s²", "rad/s²"]


def test_the_data_commit_is_the_input_files_repository(tmp_path):
    """Installed dualid has no source commit; the run records the commit of the repository holding the logs,
    '-dirty' when an input file changed or is untracked, and nothing outside a repository."""
    import subprocess

    from dualid.report.metadata import data_commit, metadata_items, run_metadata

    repo = tmp_path / "robot"
    (repo / "logs").mkdir(parents=True)
    log = repo / "logs" / "run.csv"
    log.write_text("t\n0\n")
    git = ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    assert data_commit([log]) is None  # no commit yet
    head = _commit_all(repo)
    assert data_commit([tmp_path / "missing.csv", log]) == {"commit": head, "repository": str(repo.resolve())}
    (repo / "other.txt").write_text("not an input")
    assert data_commit([log])["commit"] == head  # only the input files decide "-dirty"
    log.write_text("t\n1\n")
    assert data_commit([log])["commit"] == head + "-dirty"
    outside = tmp_path / "loose.csv"
    outside.write_text("t\n0\n")
    assert data_commit([outside]) is None
    rows = dict(metadata_items(run_metadata({"train": [log]}, "dualid fit")))
    assert rows["data commit"] == f"{head}-dirty ({repo.resolve()})"
    assert dict(metadata_items(run_metadata({"train": [outside]}, "x")))["data commit"].startswith("(the input files")


def test_a_note_several_methods_share_is_shown_once():
    from dualid.report.fit_report import notes_once

    notes = ["wls: first fitted with: ols", "dm: weight: gls", "dm: first fitted with: ols", "no method here"]
    assert notes_once(notes) == ["wls, dm: first fitted with: ols", "dm: weight: gls", "no method here"]


def test_every_method_and_reference_has_its_own_colour():
    from dualid.estimators.methods import METHODS, TRUTH
    from dualid.report.signals import REFERENCE_COLORS, color, style

    colours = [m.color.lower() for m in METHODS.values()] + [TRUTH.color.lower()]
    assert len(set(colours)) == len(colours)
    assert not {c.lower() for c in REFERENCE_COLORS} & set(colours)
    assert color("lab model 2.0", 6) != color("lab model 2.1", 7) and style("lab model 2.0", 6)[1]  # dashed
    assert style("dm", 5) == (METHODS["dm"].color, False)


def test_score_bars_are_as_tall_as_their_means_with_whiskers_over_runs():
    from dualid.report.svgplot import score_svg

    t = np.linspace(0.0, 1.0, 50)
    tau = np.stack([np.sin(2 * np.pi * t), 0.5 * np.cos(2 * np.pi * t)], axis=1)
    one = {"ols": _validation("ols", tau + [0.1, 0.02]), "lab": _validation("lab", tau + [0.2, 0.04])}
    svg = score_svg(one)
    check_html(f"<!DOCTYPE html><html><body>{svg}</body></html>")
    rects = re.findall(r'<rect ([^>]*) x="[^"]*" y="[^"]*" width="[^"]*" height="([^"]*)"><title>([^<]*)</title>', svg)
    heights = {title: float(h) for _, h, title in rects}
    assert heights["lab, J1: 0.2"] == pytest.approx(2 * heights["ols, J1: 0.1"], rel=0.02)
    assert heights["lab, J2: 0.04"] == pytest.approx(2 * heights["ols, J2: 0.02"], rel=0.05)
    looks = {title.split(",")[0]: look for look, _, title in rects}
    assert "stroke-dasharray" in looks["lab"] and "stroke-dasharray" not in looks["ols"]  # a reference: pale, dashed
    assert "<path" not in svg  # one run: no whiskers
    two = {"ols": Validation("ols", ("J1", "J2"), one["ols"].runs + one["lab"].runs)}
    assert "ols, J1: 0.15 ± 0.05" in score_svg(two) and "<path" in score_svg(two)


def test_friction_curves_are_drawn_on_linear_axes():
    from dualid.report.svgplot import curves_svg

    v = np.linspace(-2.0, 2.0, 21)
    svg = curves_svg("f", [("J1", v, {"a": 2 * v, "b": -v})], "velocity", "N m", {"a": ("#000000", False),
                                                                                 "b": ("#111111", True)})
    curves = {title: np.array([[float(c) for c in p.split(",")] for p in points.split()])
              for points, title in re.findall(r'points="([^"]*)"><title>([^<]*)</title>', svg)}
    (xa, ya), (xb, yb) = curves["a"].T, curves["b"].T
    slope_a, slope_b = np.polyfit(xa, ya, 1)[0], np.polyfit(xb, yb, 1)[0]
    assert slope_a == pytest.approx(-2 * slope_b, rel=1e-2) and slope_a < 0  # y grows upwards: pixels downwards
    assert np.allclose(xa, xb) and np.ptp(xa) > 200
