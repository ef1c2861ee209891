"""``dualid bench`` and dualid.bench.runner: a tiny run through the CLI, the writers on the committed results."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from dualid.bench.runner import (
    BenchConfig,
    base_samples,
    build_problem,
    load_results,
    parse_caps,
    time_ratios,
)
from dualid.cli import app
from dualid.report.bench import to_markdown

ROOT = Path(__file__).resolve().parents[1]
COMMITTED = ROOT / "benchmarks" / "solvers"
runner = CliRunner()
SMALL = ["--max-n", "100", "--problems", "crazyflie"]


def _out(result) -> str:
    return " ".join((result.output + (result.stderr if result.stderr_bytes is not None else "")).split())


@pytest.fixture(scope="module")
def bench_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "out"
    result = runner.invoke(app, ["bench", "--out", str(out), *SMALL, "--solvers", "newton,sdp_clarabel"])
    assert result.exit_code == 0, _out(result)
    return out


def test_bench_writes_json_markdown_and_plot(bench_dir):
    assert sorted(p.name for p in bench_dir.iterdir()) == [".dualid-manifest.json", "results.json", "results.md", "scaling.png"]
    assert (bench_dir / "scaling.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = json.loads((bench_dir / "results.json").read_text())
    assert {"machine", "noise", "base_samples", "config", "runs"} <= set(result)
    assert result["base_samples"] == 100  # only as many distinct states as the largest N needs
    assert result["config"]["solvers"] == ["newton", "sdp_clarabel"]
    runs = {r["solver"]: r for r in result["runs"]}
    assert sorted(runs) == ["newton", "sdp_clarabel"]
    for r in runs.values():
        assert (r["problem"], r["N"], r["n"], r["p"], r["status"]) == ("crazyflie", 100, 8, 30, "optimal")
        assert r["wall_time_s"] > 0 and r["peak_rss_GB"] >= r["data_GB"] > 0
    assert runs["sdp_clarabel"]["objective_gap_to_sdp_clarabel"] == 0.0
    assert abs(runs["newton"]["objective_gap_to_sdp_clarabel"]) < 1e-6  # the accuracy target: same optimum to 1e-6
    assert (bench_dir / "results.md").read_text() == to_markdown(result)


def test_bench_refuses_a_non_empty_directory_without_force(bench_dir):
    before = (bench_dir / "results.json").read_text()
    result = runner.invoke(app, ["bench", "--out", str(bench_dir), *SMALL, "--solvers", "newton"])
    assert result.exit_code == 2
    assert "exists and is not empty; choose another or pass --force" in _out(result)
    assert (bench_dir / "results.json").read_text() == before


def test_bench_force_overwrites(tmp_path):
    (tmp_path / "old.txt").write_text("x")
    result = runner.invoke(app, ["bench", "--out", str(tmp_path), *SMALL, "--solvers", "newton", "--force"])
    assert result.exit_code == 0, _out(result)
    runs = json.loads((tmp_path / "results.json").read_text())["runs"]
    assert [(r["solver"], r["N"]) for r in runs] == [("newton", 100)]


@pytest.mark.parametrize(
    "args,message",
    [
        (["--solvers", "newton,cvx"], "unknown solver 'cvx'; expected one of newton, ols_constrained, sdp_clarabel, sdp_scs"),
        (["--problems", "quadruped"], "unknown problem 'quadruped'; expected one of crazyflie, arm7"),
        (["--max-n", "10"], "max_n: expected at least 100 (the smallest N), got 10"),
        (["--cap", "arm7:100"], "cap: expected PROBLEM=N (e.g. arm7=100000), got 'arm7:100'"),
    ],
)
def test_bench_bad_options(tmp_path, args, message):
    result = runner.invoke(app, ["bench", "--out", str(tmp_path / "out"), *args])
    assert result.exit_code == 2
    assert message in _out(result)
    assert not (tmp_path / "out").exists()


def test_config_plans_sdp_only_up_to_its_limit_and_quick_skips_scs():
    config = BenchConfig(problems=("arm7",), max_n=10_000, sdp_max_n=1_000, caps={"arm7": 1_000})
    assert config.planned() == [("arm7", s, N) for N in (100, 1_000)
                                for s in ("newton", "ols_constrained", "sdp_clarabel", "sdp_scs")]
    quick = BenchConfig.quick()
    assert max(N for _, _, N in quick.planned()) == 1_000
    assert "sdp_scs" not in quick.solvers and "sdp_clarabel" in quick.solvers
    with pytest.raises(ValueError, match="caps: unknown problem 'arm8'"):
        BenchConfig(caps={"arm8": 10})
    assert parse_caps("arm7=100000, crazyflie=10") == {"arm7": 100_000, "crazyflie": 10}


def test_larger_n_repeats_the_base_states_with_fresh_noise(tmp_path):
    path = base_samples("crazyflie", tmp_path, 50)
    small, large = build_problem(path, 50), build_problem(path, 120)
    np.testing.assert_array_equal(large.Y[:50], small.Y)
    np.testing.assert_array_equal(large.Y[50:100], small.Y)
    assert not np.allclose(large.tau[50:100], large.tau[:50])  # same states, different noise
    # fewer samples are a prefix of more (fixed seeds)
    np.testing.assert_array_equal(np.load(base_samples("crazyflie", tmp_path, 20))["Y"], small.Y[:20])


def test_markdown_writer_reproduces_the_committed_table():
    result = load_results(COMMITTED / "results.json")
    assert to_markdown(result) == (COMMITTED / "results.md").read_text()


def test_time_ratios_on_the_committed_results():
    result = load_results(COMMITTED / "results.json")
    ratios = time_ratios(result, "newton", "sdp_clarabel")
    assert ratios["crazyflie", 1_000] == pytest.approx(10.864 / 0.2122, rel=1e-3)  # results.md: 10.864 s / 0.212 s
    assert ("crazyflie", 100_000) not in ratios  # no SDP run there


def test_load_results_names_what_is_missing(tmp_path):
    path = tmp_path / "results.json"
    path.write_text(json.dumps({"machine": {}, "runs": []}))
    with pytest.raises(ValueError, match="missing noise, base_samples"):
        load_results(path)
