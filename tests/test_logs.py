"""Loading logs through a column map, the on-disk data set format, and the DFKI real-data workflow."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from dualid.data import ColumnMap, Trajectory, load_dataset, load_log, load_logs
from dualid.data.preprocessing import differentiate, preprocess, sample_rate
from dualid.errors import DataError, OutputError
from dualid.report.dataset import save_dataset

JOINTS = ["Joint1", "Joint2"]
DFKI = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data"  # shipped with the repository


def frame(T=200, rate=100.0):
    t = np.arange(T) / rate
    return pd.DataFrame(
        {
            "time": t,
            "pos_meas1": np.sin(t),
            "pos_meas2": np.cos(t),
            "vel_meas1": np.cos(t),
            "vel_meas2": -np.sin(t),
            "tau_meas1": 0.1 * t,
            "tau_meas2": -0.2 * t,
            "other": 1.0,
        }
    )


def write(df, path: Path) -> Path:
    if path.suffix == ".csv":
        df.to_csv(path, index=False)
    elif path.suffix == ".parquet":
        df.to_parquet(path, index=False)
    else:
        np.savez(path, **{c: df[c].to_numpy() for c in df.columns})
    return path


# --- column maps ---------------------------------------------------------------------------------
def test_column_map_from_dict_equals_pattern():
    d = {
        "time": "time",
        "joints": {
            "Joint1": {"position": "pos_meas1", "velocity": "vel_meas1", "effort": "tau_meas1"},
            "Joint2": {"position": "pos_meas2", "velocity": "vel_meas2", "effort": "tau_meas2"},
        },
        "units": {"position": "rad"},
    }
    a, b = ColumnMap.from_dict(d), ColumnMap.pattern(JOINTS)
    assert a == b
    assert ColumnMap.from_dict(a.to_dict()) == a
    assert a.unit("effort") == "N m" and a.joint_names == tuple(JOINTS)
    c = ColumnMap.pattern(JOINTS, position="{name}_q", velocity=None, effort="{name}_tau")
    assert c.joints[1].position == "Joint2_q" and c.joints[0].velocity is None


def test_column_map_errors():
    with pytest.raises(DataError, match=r"column map: units.position: unknown position unit 'grad'; allowed: \['rad', 'deg', 'm', 'mm'\]"):
        ColumnMap.pattern(JOINTS, units={"position": "grad"})
    with pytest.raises(DataError, match=r"column map: units.time: unknown time unit 'min'; allowed: \['s', 'ms', 'us'\]"):
        ColumnMap.pattern(JOINTS, units={"time": "min"})
    with pytest.raises(DataError, match=r"column map: units.effort: unknown effort unit 'kN m'; allowed: \['N m', 'N mm', 'N'\]"):
        ColumnMap.from_dict({"time": "t", "joints": {"j": {"position": "p", "effort": "e"}}, "units": {"effort": "kN m"}})
    with pytest.raises(DataError, match=r"column map: unknown quantity 'angle' in units"):
        ColumnMap.pattern(JOINTS, units={"angle": "rad"})
    with pytest.raises(DataError, match=r"column map: joint 'j' needs columns for \['effort'\]"):
        ColumnMap.from_dict({"joints": {"j": {"position": "p"}}})
    with pytest.raises(DataError, match=r"column map: joint 'j' has unknown keys \['torque'\]"):
        ColumnMap.from_dict({"joints": {"j": {"position": "p", "torque": "x", "effort": "e"}}})
    with pytest.raises(DataError, match=r"column map: unknown keys \['rate'\]"):
        ColumnMap.from_dict({"joints": {}, "rate": 3})


# --- loading -------------------------------------------------------------------------------------
@pytest.mark.parametrize("ext", [".csv", ".parquet", ".npz"])
def test_load_log_each_format(tmp_path, ext):
    df = frame()
    path = write(df, tmp_path / f"run{ext}")
    traj = load_log(path, ColumnMap.pattern(JOINTS), JOINTS)
    assert isinstance(traj, Trajectory) and traj.name == "run"
    np.testing.assert_allclose(traj.t, df.time)
    np.testing.assert_allclose(traj.q, df[["pos_meas1", "pos_meas2"]])
    np.testing.assert_allclose(traj.v, df[["vel_meas1", "vel_meas2"]])
    np.testing.assert_allclose(traj.tau, df[["tau_meas1", "tau_meas2"]])
    assert traj.a is None and traj.coordinates == tuple(JOINTS)
    assert traj.meta["source"] == str(path)
    assert traj.meta["columns"] == ColumnMap.pattern(JOINTS).to_dict()
    assert traj.meta["units"]["position"] == "rad" and traj.meta["logged"] == ["q", "tau", "v"]


def test_units_are_converted_to_si(tmp_path):
    df = frame()
    raw = df.copy()
    raw["time"] *= 1e3
    for c in ("pos_meas1", "pos_meas2", "vel_meas1", "vel_meas2"):
        raw[c] = np.degrees(df[c])
    for c in ("tau_meas1", "tau_meas2"):
        raw[c] = df[c] * 1e3
    raw["acc1"], raw["acc2"] = np.degrees(-df.pos_meas1), np.degrees(-df.pos_meas2)
    units = {"time": "ms", "position": "deg", "velocity": "deg/s", "effort": "N mm", "acceleration": "deg/s^2"}
    cmap = ColumnMap.pattern(JOINTS, acceleration="acc{i}", units=units)
    traj = load_log(write(raw, tmp_path / "run.csv"), cmap)
    np.testing.assert_allclose(traj.t, df.time, atol=1e-12)
    np.testing.assert_allclose(traj.q, df[["pos_meas1", "pos_meas2"]], atol=1e-12)
    np.testing.assert_allclose(traj.v, df[["vel_meas1", "vel_meas2"]], atol=1e-12)
    np.testing.assert_allclose(traj.tau, df[["tau_meas1", "tau_meas2"]], atol=1e-12)
    np.testing.assert_allclose(traj.a, -df[["pos_meas1", "pos_meas2"]].to_numpy(), atol=1e-12)
    assert traj.meta["units"] == units


def test_model_joint_order_and_mismatches(tmp_path):
    path = write(frame(), tmp_path / "run.csv")
    swapped = load_log(path, ColumnMap.pattern(JOINTS), ["Joint2", "Joint1"])
    assert swapped.coordinates == ("Joint2", "Joint1")
    np.testing.assert_allclose(swapped.q[:, 0], frame().pos_meas2)
    with pytest.raises(DataError, match=r"column map names joints \['Joint2'\] that are not in the model; "
                       r"model joints: \['Joint1', 'shoulder'\]"):
        load_log(path, ColumnMap.pattern(JOINTS), ["Joint1", "shoulder"])
    with pytest.raises(DataError, match=r"column map has no columns for model joints \['Joint3'\]; "
                       r"mapped: \['Joint1', 'Joint2'\]"):
        load_log(path, ColumnMap.pattern(JOINTS), JOINTS + ["Joint3"])


def test_load_errors(tmp_path):
    cmap = ColumnMap.pattern(JOINTS)
    missing = tmp_path / "nope.csv"
    with pytest.raises(FileNotFoundError, match=f"log file not found: {missing}"):
        load_log(missing, cmap)
    txt = tmp_path / "run.txt"
    txt.write_text("time\n0\n")
    with pytest.raises(DataError, match=r"run.txt: unknown log format '.txt'; expected one of .csv, .parquet, .npz"):
        load_log(txt, cmap)
    df = frame().drop(columns=["tau_meas2", "vel_meas1"])
    with pytest.raises(DataError, match=r"missing columns \['vel_meas1', 'tau_meas2'\]; available columns: "
                       r"\['time', 'pos_meas1', 'pos_meas2', 'vel_meas2', 'tau_meas1', 'other'\]"):
        load_log(write(df, tmp_path / "cols.csv"), cmap)
    df = frame()
    df.loc[7, "time"] = df.loc[6, "time"]
    with pytest.raises(DataError, match=r"time column 'time' repeats a time stamp: rows 6 and 7 both have 0.06"):
        load_log(write(df, tmp_path / "mono.csv"), cmap)
    df = frame()
    df.loc[12, "pos_meas2"] = np.nan
    df.loc[30, "pos_meas2"] = np.inf
    with pytest.raises(DataError, match=r"column 'pos_meas2' has non-finite values \(NaN or inf\), first at row 12"):
        load_log(write(df, tmp_path / "nan.csv"), cmap)
    df = frame()
    df.loc[3, "tau_meas1"] = -np.inf
    with pytest.raises(DataError, match=r"column 'tau_meas1' has non-finite values \(NaN or inf\), first at row 3"):
        load_log(write(df, tmp_path / "inf.npz"), cmap)
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(DataError, match=r"empty.csv: log is empty \(no rows\)"):
        load_log(empty, cmap)
    header = write(frame().iloc[:0], tmp_path / "header.csv")
    with pytest.raises(DataError, match=r"header.csv: log is empty \(no rows\)"):
        load_log(header, cmap)
    with pytest.raises(DataError, match=r"header.parquet: log is empty \(no rows\)"):
        load_log(write(frame().iloc[:0], tmp_path / "header.parquet"), cmap)


def test_missing_velocity_needs_explicit_choice(tmp_path):
    df = frame(T=500, rate=200.0)
    path = write(df.drop(columns=["vel_meas1", "vel_meas2"]), tmp_path / "nov.parquet")
    cmap = ColumnMap.pattern(JOINTS, velocity=None)
    with pytest.raises(DataError, match=r"column map has no velocity columns: map a velocity column for each "
                       r"joint, or load with velocity='gradient' and then call preprocessing.differentiate"):
        load_log(path, cmap)
    traj = load_log(path, cmap, velocity="gradient")
    assert traj.meta["logged"] == ["q", "tau"]
    np.testing.assert_allclose(traj.v[5:-5], df[["vel_meas1", "vel_meas2"]][5:-5], atol=1e-4)
    out = differentiate(traj, window=0.1)  # v not logged: replaced
    assert out.meta["steps"][-1]["differentiate"]["velocity"] is True
    np.testing.assert_allclose(out.v[20:-20], df[["vel_meas1", "vel_meas2"]][20:-20], atol=1e-6)


def test_partial_maps_and_single_row(tmp_path):
    path = write(frame(), tmp_path / "run.csv")
    d = ColumnMap.pattern(JOINTS).to_dict()
    del d["joints"]["Joint2"]["velocity"]
    with pytest.raises(DataError, match=r"velocity columns for some joints only \(missing for \['Joint2'\]\)"):
        load_log(path, d)
    with pytest.raises(DataError, match=r"one.csv: log has 1 row; need at least 2"):
        load_log(write(frame().iloc[:1], tmp_path / "one.csv"), ColumnMap.pattern(JOINTS))
    with pytest.raises(DataError, match=r"load_log: velocity must be 'logged' or 'gradient', got 'none'"):
        load_log(path, ColumnMap.pattern(JOINTS), velocity="none")


def test_load_logs_list(tmp_path):
    paths = [write(frame(), tmp_path / f"r{k}.csv") for k in range(3)]
    runs = load_logs(paths, ColumnMap.pattern(JOINTS).to_dict(), JOINTS)
    assert [r.name for r in runs] == ["r0", "r1", "r2"]


# --- data sets -----------------------------------------------------------------------------------
def _runs(k0, n, with_a=True):
    out = []
    for k in range(k0, k0 + n):
        t = np.arange(50) / 100.0
        q = np.stack([np.sin(t + k), np.cos(t), t], axis=1)
        meta = {"source": f"sim{k}", "steps": [{"resample": {"rate": 100.0}}]}
        out.append(Trajectory(t=t, q=q, v=2 * q, tau=3 * q, a=4 * q if with_a else None,
                              coordinates=("x", "y", "z"), name=f"run{k}", meta=meta))
    return out


@pytest.mark.parametrize("fmt", ["parquet", "npz"])
def test_dataset_round_trip(tmp_path, fmt):
    splits = {"train": _runs(0, 2), "test": _runs(5, 1, with_a=False)}
    info = {"theta_true": np.array([0.5, 0.02]), "parameter_names": ["m", "b"], "system": "toy"}
    d = save_dataset(tmp_path / "ds", splits, info, fmt=fmt)
    assert sorted(p.name for p in d.iterdir()) == [".dualid-manifest.json", "dataset.json", "test", "train"]
    assert (d / "train" / f"run_000.{fmt}").is_file()
    back, info_back = load_dataset(d)
    assert info_back == {"theta_true": [0.5, 0.02], "parameter_names": ["m", "b"], "system": "toy"}
    assert list(back) == ["train", "test"]
    for split, runs in splits.items():
        assert len(back[split]) == len(runs)
        for a, b in zip(runs, back[split]):
            assert (a.name, a.coordinates, a.meta) == (b.name, b.coordinates, b.meta)
            for key in ("t", "q", "v", "tau", "a"):
                x, y = getattr(a, key), getattr(b, key)
                assert (x is None) == (y is None)
                if x is not None:
                    np.testing.assert_array_equal(x, y)


def test_dataset_overwrite_guard(tmp_path):
    d = tmp_path / "ds"
    save_dataset(d, {"train": _runs(0, 3)}, {}, fmt="npz")
    with pytest.raises(OutputError, match=f"output directory {d}: exists and is not empty; choose another or pass --force"):
        save_dataset(d, {"train": _runs(0, 1)}, {})
    (d / "notes.txt").write_text("keep me")
    save_dataset(d, {"val": _runs(0, 1)}, {"v": 2}, overwrite=True)
    back, info = load_dataset(d)
    assert list(back) == ["val"] and info == {"v": 2}
    assert not (d / "train").exists() and (d / "notes.txt").read_text() == "keep me"
    with pytest.raises(DataError, match=r"save_dataset: fmt must be 'parquet' or 'npz', got 'hdf5'"):
        save_dataset(tmp_path / "x", {"train": _runs(0, 1)}, {}, fmt="hdf5")
    with pytest.raises(FileNotFoundError, match=r"no dataset.json in"):
        load_dataset(tmp_path)


# --- real data -----------------------------------------------------------------------------------
def test_dfki_double_pendulum_log():
    raw = load_log(DFKI / "trajectory_00.csv", ColumnMap.pattern(JOINTS), JOINTS)
    assert raw.q.shape == (raw.T, 2) and raw.T > 4000
    with pytest.raises(DataError, match="time stamps are not uniform"):
        sample_rate(raw.t, rtol=0.01)  # the first steps are 3.3 ms, then 2 ms
    config = [
        {"resample": {"rate": 500}},
        {"differentiate": {"method": "savgol", "window": 0.05, "velocity": True}},
        {"filter_lowpass": {"cutoff": 20}},
        {"downsample": {"factor": 5}},
    ]
    out = preprocess(raw, config)
    assert sample_rate(out.t, rtol=1e-6) == pytest.approx(100.0)
    T = out.T
    assert T == pytest.approx((raw.t[-1] - raw.t[0]) * 100, abs=2)
    assert out.q.shape == out.v.shape == out.a.shape == out.tau.shape == (T, 2)
    assert [next(iter(s)) for s in out.meta["steps"]] == [next(iter(c)) for c in config]
    logged_v = np.stack([np.interp(out.t, raw.t, raw.v[:, j]) for j in range(2)], axis=1)
    for j in range(2):
        assert np.corrcoef(out.v[:, j], logged_v[:, j])[0, 1] > 0.95


def test_array_meta_goes_to_a_side_file_and_comes_back(tmp_path):
    from dualid.data import Trajectory
    from dualid.data.dataset import load_dataset
    from dualid.report.dataset import save_dataset

    t = np.arange(5) * 0.1
    truth = {"q": np.arange(10.0).reshape(5, 2), "note": "exact"}
    traj = Trajectory(t, np.zeros((5, 2)), np.zeros((5, 2)), np.ones((5, 2)), None, ("a", "b"), "r", {"true": truth, "k": 3})
    save_dataset(tmp_path / "d", {"train": [traj]}, {})
    index = (tmp_path / "d" / "dataset.json").read_text()
    assert "meta.npz" in index and "9.0" not in index  # the array is not written into the JSON
    runs, _ = load_dataset(tmp_path / "d")
    meta = runs["train"][0].meta
    np.testing.assert_array_equal(meta["true"]["q"], truth["q"])
    assert meta["true"]["note"] == "exact" and meta["k"] == 3


# --- inputs people log ---------------------------------------------------------------
@pytest.mark.parametrize("spelling", ["N m", "Nm", "N·m", "N*m", "N.m", " N  m "])
def test_torque_unit_spellings_are_one_unit(spelling):
    cmap = ColumnMap.pattern(JOINTS, units={"effort": spelling})
    assert cmap.unit("effort") == "N m"


def test_per_joint_units_convert_each_joint(tmp_path):
    df = frame()
    df["pos_meas2"] = np.degrees(df["pos_meas2"])
    df["vel_meas2"] = np.degrees(df["vel_meas2"])
    df["tau_meas1"] = 1000 * df["tau_meas1"]
    cmap = ColumnMap.from_dict({"joints": ColumnMap.pattern(JOINTS).to_dict()["joints"],
                                "units": {"position": {"Joint2": "deg"}, "velocity": {"Joint2": "deg/s"},
                                          "effort": {"Joint1": "N mm", "Joint2": "Nm"}}})
    traj = load_log(write(df, tmp_path / "run.csv"), cmap)
    ref = frame()
    np.testing.assert_allclose(traj.q, ref[["pos_meas1", "pos_meas2"]].to_numpy(), atol=1e-12)
    np.testing.assert_allclose(traj.v, ref[["vel_meas1", "vel_meas2"]].to_numpy(), atol=1e-12)
    np.testing.assert_allclose(traj.tau, ref[["tau_meas1", "tau_meas2"]].to_numpy(), atol=1e-12)
    assert cmap.unit("position", "Joint2") == "deg" and cmap.unit("position", "Joint1") == "rad"
    assert ColumnMap.from_dict(cmap.to_dict()) == cmap  # the per-joint form round-trips


def test_linear_units_of_prismatic_joints():
    cmap = ColumnMap.pattern(JOINTS, units={"position": "mm", "velocity": "mm/s", "effort": "N"})
    assert cmap.unit("position") == "mm" and cmap.unit("effort") == "N"


def test_per_joint_units_must_name_mapped_joints():
    with pytest.raises(DataError, match=r"units.position names joints \['Joint9'\] that are not mapped"):
        ColumnMap.pattern(JOINTS, units={"position": {"Joint9": "deg"}})


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_two_dimensional_arrays_are_addressed_by_name_and_index(tmp_path, suffix):
    df = frame()
    q = df[["pos_meas1", "pos_meas2"]].to_numpy()
    v = df[["vel_meas1", "vel_meas2"]].to_numpy()
    tau = df[["tau_meas1", "tau_meas2"]].to_numpy()
    path = tmp_path / f"run{suffix}"
    if suffix == ".npz":
        np.savez(path, t=df["time"].to_numpy(), q=q, v=v, tau=tau)
    else:
        pd.DataFrame({"t": df["time"], "q": list(q), "v": list(v), "tau": list(tau)}).to_parquet(path)
    cmap = ColumnMap.pattern(JOINTS, position="q[{k}]", velocity="v[{k}]", effort="tau[{k}]", time="t")
    traj = load_log(path, cmap)
    np.testing.assert_array_equal(traj.q, q)
    np.testing.assert_array_equal(traj.v, v)
    np.testing.assert_array_equal(traj.tau, tau)
    reordered = load_log(path, cmap, joints=["Joint2", "Joint1"])  # coordinates follow the model's order
    np.testing.assert_array_equal(reordered.q, q[:, ::-1])


def test_three_dimensional_npz_arrays_are_refused(tmp_path):
    path = tmp_path / "run.npz"
    np.savez(path, t=np.arange(5.0), q=np.zeros((5, 2, 2)))
    with pytest.raises(DataError, match=r"array 'q' has shape \(5, 2, 2\); expected \(T,\) channels or \(T, n\) arrays"):
        load_log(path, ColumnMap.pattern(JOINTS, position="q[{k}]", effort="q[{k}]", velocity=None, time="t"),
                 velocity="gradient")


def test_motor_current_times_torque_constant_gear_ratio_and_efficiency(tmp_path):
    df = frame()
    kt, gear, eta = 0.08, 6.0, 0.9
    df["I1"] = df["tau_meas1"] / (kt * gear * eta)
    joints = ColumnMap.pattern(JOINTS).to_dict()["joints"]
    joints["Joint1"]["effort"] = {"current": "I1", "torque_constant": kt, "gear_ratio": gear, "efficiency": eta}
    cmap = ColumnMap.from_dict({"joints": joints})
    traj = load_log(write(df, tmp_path / "run.csv"), cmap)
    np.testing.assert_allclose(traj.tau, frame()[["tau_meas1", "tau_meas2"]].to_numpy(), atol=1e-12)
    assert ColumnMap.from_dict(cmap.to_dict()) == cmap
    joints["Joint1"]["effort"] = {"current": "I1", "torque_constant": kt, "efficiency": 1.5}
    with pytest.raises(DataError, match=r"joint 'Joint1' effort.efficiency: expected a number in \(0, 1\], got 1.5"):
        ColumnMap.from_dict({"joints": joints})
    joints["Joint1"]["effort"] = {"current": "I1"}
    with pytest.raises(DataError, match=r"joint 'Joint1' effort: a motor current needs \['torque_constant'\]"):
        ColumnMap.from_dict({"joints": joints})
