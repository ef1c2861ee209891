"""Regenerate the floating-base demo logs (CSV, as a user would have them) and their URDFs.

    python examples/floating/make_logs.py                 # writes examples/floating/{box,crazyflie}/ (seed 14)
    python examples/floating/make_logs.py OUT_DIR SEED    # another data seed elsewhere

Two simulated systems, each logged the way its lab would log it, with realistic noise:

box/        A free-flying rigid box in zero gravity (think of a space robot's test body), pushed by
            a known wrench at a handle 5 cm off its centre (force and torque in the handle's own
            frame, from a force-torque sensor). Pinocchio ``aba`` with the wrench as ``fext``, RK4 on
            the Lie group at 1 kHz, logged at 100 Hz. Columns: time, base position, quaternion
            (motion capture: 0.5 mm, 0.3°; exported with qw ≥ 0, so the sign flips when qw crosses 0),
            and the 6 wrench columns (force-torque sensor: 1 % gain error, 0.05 N / 0.005 N m noise).
crazyflie/  The study's Crazyflie–pendulum simulator (dualid.systems.crazyflie: geometric controller,
            motor lag, rotor drag and universal-joint friction unmodelled, thrust-calibration error).
            Its coordinates are Pinocchio's free flyer (position, quaternion (x, y, z, w), LOCAL body
            velocity) plus the two universal-joint angles. Logged: motion capture of the quadrotor and
            of the pendulum (pose noise 0.5 mm, 0.3°) -> base pose and the two joint angles, and the
            thrust wrench on the airframe computed from the commanded PWM and the measured battery
            voltage through the firmware's thrust curve (the only force a user has). The thrust is an
            external wrench on base_link in its own frame (force (0, 0, Σf), torque from the mixer);
            the pendulum joints are passive (effort 0).

The URDFs carry CAD-like inertials that are deliberately off the truth (the prior a user has).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

HERE = Path(__file__).resolve().parent
RATE = 100.0  # [Hz] logging


# --- shared -------------------------------------------------------------------------------------
def _inertial(I: pin.Inertia) -> str:
    c, Ic = I.lever, I.inertia
    return (f'<inertial><origin xyz="{c[0]:.6g} {c[1]:.6g} {c[2]:.6g}" rpy="0 0 0"/><mass value="{I.mass:.6g}"/>'
            f'<inertia ixx="{Ic[0, 0]:.6g}" ixy="{Ic[0, 1]:.6g}" ixz="{Ic[0, 2]:.6g}" iyy="{Ic[1, 1]:.6g}" '
            f'iyz="{Ic[1, 2]:.6g}" izz="{Ic[2, 2]:.6g}"/></inertial>')


def _mocap(q_base: np.ndarray, rng, pos_std=5e-4, ang_std=np.deg2rad(0.3)):
    """Noisy position (T, 3) and rotation (T, 3, 3) of a free-flyer configuration (T, 7)."""
    T = q_base.shape[0]
    R = Rotation.from_quat(q_base[:, 3:7])
    noise = Rotation.from_rotvec(ang_std * rng.standard_normal((T, 3)))
    return q_base[:, :3] + pos_std * rng.standard_normal((T, 3)), (R * noise)


def _quat_columns(R: Rotation) -> np.ndarray:
    """(T, 4) x, y, z, w with w ≥ 0, as mocap software exports them (sign flips where w crosses 0)."""
    quat = R.as_quat()
    return quat * np.where(quat[:, 3:4] < 0, -1.0, 1.0)


def _write_csv(path: Path, columns: dict[str, np.ndarray], formats: dict[str, str]) -> None:
    names = list(columns)
    data = np.column_stack([columns[n] for n in names])
    fmt = [formats.get(n, "%.6g") for n in names]
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt=fmt)


# --- the box ------------------------------------------------------------------------------------
BOX_MASS, BOX_SIZE, BOX_COM = 4.0, (0.40, 0.30, 0.20), (0.012, -0.008, 0.005)  # [kg, m, m] truth
HANDLE = (0.05, 0.02, 0.0)  # [m] handle frame in the box frame


def _box_inertia(mass, size, com) -> pin.Inertia:
    a, b, c = size
    return pin.Inertia(mass, np.array(com), mass / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b]))


def box_urdf(inertia: pin.Inertia) -> str:
    return f"""<?xml version="1.0"?>
<!-- A free-flying box with a handle (dualid floating-base demo); inertials are a CAD-like prior. -->
<robot name="box">
  <link name="box">{_inertial(inertia)}</link>
  <link name="handle"/>
  <joint name="handle_joint" type="fixed">
    <parent link="box"/><child link="handle"/><origin xyz="{HANDLE[0]} {HANDLE[1]} {HANDLE[2]}" rpy="0 0 0"/>
  </joint>
</robot>
"""


def _push(t: np.ndarray, rng) -> np.ndarray:
    """(T, 6) wrench in the handle frame: sums of sines with random phases [N, N m] (invented)."""
    amp = np.array([3.0, 3.0, 2.5, 0.1, 0.1, 0.12])
    periods = np.array([[1.7, 0.9, 2.9], [2.3, 1.1, 0.7], [1.3, 3.1, 0.8], [1.9, 0.6, 2.7], [2.1, 1.4, 0.5], [1.6, 0.95, 3.3]])
    phase = rng.uniform(0, 2 * np.pi, periods.shape)
    return np.stack([amp[i] * np.sin(2 * np.pi * t[:, None] / periods[i] + phase[i]).sum(1) / 2 for i in range(6)], 1)


def simulate_box(urdf: Path, duration: float, rng, noisy: bool = True) -> dict[str, np.ndarray]:
    model = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    model.gravity = pin.Motion.Zero()
    model.inertias[1] = _box_inertia(BOX_MASS, BOX_SIZE, BOX_COM)  # the truth (the URDF holds the prior)
    data = model.createData()
    handle = model.frames[model.getFrameId("handle")]
    dt, sub = 1e-3, int(1e-3 ** -1 / RATE)
    T = int(duration * RATE)
    t_fine = np.arange(T * sub + 1) * dt
    w = _push(t_fine, rng)

    def accel(q, v, wrench):
        fext = pin.StdVec_Force()
        for _ in range(model.njoints):
            fext.append(pin.Force.Zero())
        fext[handle.parentJoint] = handle.placement.act(pin.Force(wrench))  # handle frame -> joint frame
        return pin.aba(model, data, q, v, np.zeros(model.nv), fext)

    q = pin.neutral(model)
    q[:3] = rng.uniform(-0.2, 0.2, 3)
    q[3:7] = Rotation.random(random_state=rng.integers(1 << 31)).as_quat()
    v = np.concatenate([rng.normal(0, 0.05, 3), rng.normal(0, 0.3, 3)])
    out_q, out_w = [], []
    for k in range(T * sub):
        if k % sub == 0:
            out_q.append(q.copy())
            out_w.append(w[k].copy())
        wk, wm = w[k], 0.5 * (w[k] + w[k + 1])  # RK4 with the wrench at t, t + dt/2, t + dt
        a1 = accel(q, v, wk)
        a2 = accel(pin.integrate(model, q, 0.5 * dt * v), v + 0.5 * dt * a1, wm)
        a3 = accel(pin.integrate(model, q, 0.5 * dt * (v + 0.5 * dt * a1)), v + 0.5 * dt * a2, wm)
        a4 = accel(pin.integrate(model, q, dt * (v + 0.5 * dt * a2)), v + dt * a3, w[k + 1])
        q = pin.integrate(model, q, dt / 6 * (v + 2 * (v + 0.5 * dt * a1) + 2 * (v + 0.5 * dt * a2) + v + dt * a3))
        v = v + dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
    q_true, wrench = np.array(out_q), np.array(out_w)
    p, R = _mocap(q_true, rng, *((5e-4, np.deg2rad(0.3)) if noisy else (0.0, 0.0)))
    gain = 1.0 + 0.01 * noisy * rng.standard_normal(6)  # force-torque sensor calibration (1 %)
    wrench_m = wrench * gain + noisy * np.array([0.05] * 3 + [0.005] * 3) * rng.standard_normal(wrench.shape)
    cols = {"time": np.arange(T) / RATE}
    cols.update({f"base_{a}": p[:, i] for i, a in enumerate("xyz")})
    cols.update({f"base_q{a}": _quat_columns(R)[:, i] for i, a in enumerate("xyzw")})
    cols.update({n: wrench_m[:, i] for i, n in enumerate(["fx", "fy", "fz", "tx", "ty", "tz"])})
    return cols


# --- the Crazyflie–pendulum ---------------------------------------------------------------------
def crazyflie_urdf(base: pin.Inertia, core: pin.Inertia, pendulum: pin.Inertia, pivot) -> str:
    return f"""<?xml version="1.0"?>
<!-- Crazyflie 2.0 with a universal-joint pendulum (dualid floating-base demo; dualid.systems.crazyflie_model).
     Inertials are the CAD-like prior (NOMINAL_THETA), not the truth. -->
<robot name="crazyflie_pendulum">
  <link name="base_link">{_inertial(base)}</link>
  <link name="core">{_inertial(core)}</link>
  <link name="pendulum">{_inertial(pendulum)}</link>
  <joint name="alpha1" type="revolute">
    <parent link="base_link"/><child link="core"/><origin xyz="{pivot[0]} {pivot[1]} {pivot[2]}" rpy="0 0 0"/>
    <axis xyz="1 0 0"/><limit lower="-1.5" upper="1.5" effort="0" velocity="50"/>
  </joint>
  <joint name="alpha2" type="revolute">
    <parent link="core"/><child link="pendulum"/><origin xyz="0 0 0" rpy="0 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="0" velocity="50"/>
  </joint>
</robot>
"""


def crazyflie_logs(urdf: Path, n_runs: int, duration: float, seed: int) -> list[dict[str, np.ndarray]]:
    from dualid.systems import crazyflie as cfs
    from dualid.systems import crazyflie_model as cfm
    from dualid.systems.crazyflie_control import random_reference

    # the URDF is the simulator's model: same mass matrix at random states with the true inertias
    truth = cfm.build_model()
    model = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    for j in range(1, model.njoints):
        model.inertias[j] = truth.inertias[j]
    for _ in range(5):
        q = pin.randomConfiguration(truth, -np.ones(truth.nq), np.ones(truth.nq))
        assert np.allclose(pin.crba(model, model.createData(), q), pin.crba(truth, truth.createData(), q), atol=1e-12)
    noise = cfs.CrazyflieNoise.realistic()
    rng = np.random.default_rng(seed)
    lo, hi = noise.gain_error
    gains = 1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi) + noise.motor_spread * rng.standard_normal(4)
    raw = cfs.simulate(random_reference(rng, n_runs), duration, noise, rng, gains=gains)
    logs = []
    for b in range(n_runs):
        q = raw.q[b]
        p, R = _mocap(q[:, :7], rng)
        R_pend = Rotation.from_quat(q[:, 3:7]) * Rotation.from_euler("XY", q[:, 7:9])
        R_pend_m = R_pend * Rotation.from_rotvec(noise.angle_std * rng.standard_normal((q.shape[0], 3)))
        alpha = cfs.shape_angles(R.as_matrix(), R_pend_m.as_matrix())
        wrench = cfs.measured_wrench(raw.pwm[b], raw.V_meas[b])[:, :6]  # thrust through the firmware's curve
        cols = {"time": raw.t}
        cols.update({f"base_{a}": p[:, i] for i, a in enumerate("xyz")})
        cols.update({f"base_q{a}": _quat_columns(R)[:, i] for i, a in enumerate("xyzw")})
        cols.update({"alpha1": alpha[:, 0], "alpha2": alpha[:, 1]})
        cols.update({n: wrench[:, i] for i, n in ((2, "thrust"), (3, "torque_x"), (4, "torque_y"), (5, "torque_z"))})
        logs.append(cols)
    return logs


FORMATS = {"time": "%.2f", **{f"base_{a}": "%.5f" for a in "xyz"}, **{f"base_q{a}": "%.5f" for a in "xyzw"},
           "alpha1": "%.5f", "alpha2": "%.5f"}


def main(out: Path = HERE, seed: int = 14) -> None:
    """Write both demos into ``out`` (box/ and crazyflie/: URDFs and CSV logs) from data seed ``seed``."""
    from dualid.systems import crazyflie_model as cfm

    rng = np.random.default_rng(seed)
    (out / "box").mkdir(parents=True, exist_ok=True)
    prior = _box_inertia(3.7, (0.41, 0.31, 0.19), (0.0, 0.0, 0.0))  # CAD: 8 % light, centred
    (out / "box" / "box.urdf").write_text(box_urdf(prior))
    for k, name in enumerate(["train_0", "train_1", "test_0"]):
        _write_csv(out / "box" / f"{name}.csv", simulate_box(out / "box" / "box.urdf", 8.0, rng),
                   {**FORMATS, **{c: "%.5g" for c in ["fx", "fy", "fz", "tx", "ty", "tz"]}})

    (out / "crazyflie").mkdir(parents=True, exist_ok=True)
    nominal = cfm._nominal_model()
    urdf = out / "crazyflie" / "crazyflie_pendulum.urdf"
    urdf.write_text(crazyflie_urdf(nominal.inertias[1], nominal.inertias[2], nominal.inertias[3], cfm.MOUNT_OFFSET))
    logs = crazyflie_logs(urdf, 4, 12.0, seed=seed)
    for cols, name in zip(logs, ["train_0", "train_1", "test_0", "test_1"]):
        _write_csv(out / "crazyflie" / f"{name}.csv", cols,
                   {**FORMATS, **{c: "%.5g" for c in ["thrust", "torque_x", "torque_y", "torque_z"]}})


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE, int(sys.argv[2]) if len(sys.argv) > 2 else 14)
