"""The YAML form of a fit config as a pydantic v2 model, for its JSON Schema (editor completion and
checking: docs/fit-config.schema.json, written by ``dualid schema``) and for checking a config's
shape with key-path messages (``check_shape``). ``FitConfig.from_dict`` stays the reference for
the values; tests keep the two in step (the same keys, the example config accepted by both).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from dualid.errors import ConfigError
from dualid.estimators.methods import METHODS
from dualid.robot.drag_schema import DragSection
from dualid.robot.margin_schema import MarginSection

Method = Literal[tuple(METHODS)]  # type: ignore[valid-type]


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ModelSection(_Section):
    urdf: str | None = Field(None, description="the robot's URDF (relative to the config file); required unless "
                                               "kind is drag with drag.chain")
    floating_base: bool = Field(False, description="add a free-flyer root joint")
    package_path: list[str] | str | None = Field(None, description="folders holding the packages that package:// mesh "
                                                 "URIs name (relative to the config file); ROS_PACKAGE_PATH is searched "
                                                 "after them")
    gravity: list[float] | None = Field(None, min_length=3, max_length=3, description="[m/s²]; default (0, 0, -9.81)")
    kind: Literal["inertia", "drag"] = Field("inertia", description="inertia: τ = M(q)a + h(q, v); drag: τ = D(q)v")
    drag: DragSection | None = Field(None, description="the drag model (kind: drag)")


class MotorEffort(_Section):
    current: str = Field(description="the motor-current column [A]")
    torque_constant: float = Field(gt=0, description="kt [N m/A]")
    gear_ratio: float = Field(1.0, gt=0)
    efficiency: float = Field(1.0, gt=0, le=1)


class JointColumnsSection(_Section):
    position: str
    effort: str | MotorEffort | Literal[0] = Field(
        description="an effort column, a motor current (τ = I·kt·N·η), or 0 for a passive joint")
    velocity: str | None = None
    acceleration: str | None = None


UnitSpec = str | dict[str, str]  # one unit, or {joint: unit}


Column = str | Literal[0]  # a column name, or 0: a component known to be zero


class BaseSection(_Section):
    position: list[str] | None = Field(None, min_length=3, max_length=3, description="[m] x, y, z of the base in the world")
    quaternion: list[str] | None = Field(None, min_length=4, max_length=4,
                                         description="world_R_base as a unit quaternion, columns in quaternion_order")
    quaternion_order: Literal["xyzw", "wxyz"] = Field("xyzw", description="xyzw (Pinocchio, ROS, scipy) or wxyz")
    matrix: list[str] | None = Field(None, min_length=16, max_length=16,
                                     description="instead of position + quaternion: world_T_base (4×4) row by row")
    twist: list[str] | None = Field(None, min_length=6, max_length=6, description="[m/s, rad/s] vx vy vz wx wy wz")
    twist_frame: Literal["local", "local_world_aligned"] = Field(
        "local", description="local: base-frame axes (Pinocchio's free flyer); local_world_aligned: world axes")


class WrenchSection(_Section):
    frame: str = Field(description="a frame of the model (URDF link or joint) the wrench acts on")
    reference: Literal["local", "local_world_aligned", "world"] = Field(
        "local", description="where the wrench is expressed (Pinocchio's ReferenceFrame)")
    force: list[Column] = Field(min_length=3, max_length=3, description="[N] columns (or 0)")
    torque: list[Column] = Field(min_length=3, max_length=3, description="[N m] columns (or 0)")


class JointStatesTopic(_Section):
    topic: str = Field(description="a sensor_msgs/JointState topic; joints matched by name")
    velocity: bool | None = Field(None, description="null: the logged velocities when every source has one (the base "
                                                    "too); false: v from dq/dt")
    names: dict[str, str] | None = Field(None, description="model joint -> its name in the messages")
    passive: list[str] | None = Field(None, description="unactuated model joints: τ = 0, their effort is not read")


class BaseTopicSection(_Section):
    topic: str = Field(description="nav_msgs/Odometry, geometry_msgs/PoseStamped (twist: false) or tf2_msgs/TFMessage")
    parent: str | None = Field(None, description="a /tf topic: the parent frame of the transform (e.g. odom)")
    child: str | None = Field(None, description="a /tf topic: the base frame (e.g. base_link)")
    twist: bool = Field(True, description="read an odometry's twist (child frame: Pinocchio's LOCAL)")


class WrenchTopicSection(_Section):
    topic: str = Field(description="a geometry_msgs/WrenchStamped topic")
    frame: str | None = Field(None, description="the model frame it acts on; default: the messages' header.frame_id")
    reference: Literal["local", "local_world_aligned", "world"] = "local"


class TopicsSection(_Section):
    stamps: Literal["header", "receive"] = Field("header", description="header.stamp or the bag's record time")
    time_base: str | None = Field(None, description="the topic whose stamps are the time base (default: the joint "
                                                    "states, else the base); the others are interpolated onto it")
    joint_states: str | JointStatesTopic | None = None
    base: str | BaseTopicSection | None = Field(None, description="the floating base's pose (and twist)")
    wrenches: dict[str, str | WrenchTopicSection] | None = Field(None, description="external wrenches by name")


class ColumnsSection(_Section):
    topics: TopicsSection | None = Field(None, description="a ROS bag's topics (instead of time, joints, base and "
                                                           "wrenches)")
    time: str = "time"
    joints: dict[str, JointColumnsSection] = Field(default_factory=dict,
                                                   description="model joint name -> its columns; 'q[k]' is column k of an array q")
    base: BaseSection | None = Field(None, description="a floating base's pose and twist (model.floating_base: true)")
    wrenches: dict[str, WrenchSection] | None = Field(None, description="external wrenches: τ = rnea − Σ J_fᵀ f")
    units: dict[Literal["time", "position", "velocity", "acceleration", "effort"], UnitSpec] = Field(default_factory=dict)


class JointTermsSection(_Section):
    viscous: bool = True
    coulomb: bool = True
    coulomb_velocity: float = Field(0.01, gt=0, description="v_c of fc·tanh(v/v_c) [rad/s]")
    armature: bool = True
    joints: list[str] | str | None = None


class PlausibleSection(_Section):
    level: float = Field(0.95, ge=0, lt=1, description="confidence level of the region; 0: keep the training "
                                                       "predictions exactly")
    joint: bool = Field(False, description="radius² χ²_r(level) (the joint region of all base parameters) instead "
                                           "of χ²₁(level) (each linear combination within its own interval)")


class PriorSection(_Section):
    source: str = Field("urdf", description="'urdf' or a parameters.yaml/json of a previous fit ('file#method')")
    gamma: float = Field(0.1, ge=0)
    per_equation: bool = Field(True, description="γ·N·n (the study's convention) instead of an absolute γ")
    plausible: bool | PlausibleSection = Field(
        True, description="write URDF/MJCF with the parameters closest to the prior among those the data do not "
                          "reject (the base parameters in the fit's confidence region); false: the raw θ̂")


class ValidationSection(_Section):
    xcorr_window: float = Field(0.02, ge=0, description="[s] shift window of the normalized cross-correlation")


class UncertaintySection(_Section):
    method: Literal["sandwich", "bootstrap", "none"] = Field(
        "sandwich", description="95 % intervals of the base parameters: sandwich covariance or block bootstrap")
    blocks: Literal["segments", "runs"] = Field("segments", description="blocks of correlated samples")
    segments_per_run: int | None = Field(None, ge=1, description="null: 10 per base parameter (≥ 100) in all")
    resamples: int = Field(200, ge=10, description="bootstrap refits")
    seed: int = Field(0, ge=0, description="bootstrap seed")


class FitConfigSchema(_Section):
    """A real-robot fit (dualid fit --config FILE)."""

    model: ModelSection | str
    columns: ColumnsSection | None = None
    train: list[str] | str = Field(description="training logs (csv/parquet/npz, a ROS 1 .bag or a rosbag2 folder)")
    test: list[str] | str | None = None
    preprocessing: list[dict[str, dict[str, Any] | None]] | None = Field(
        None, description="steps {resample | filter_lowpass | differentiate | trim | downsample: parameters}; "
                          "omit to derive them from the first log's rate and motion band")
    joint_terms: JointTermsSection | None = None
    bounds: dict[str, tuple[float | None, float | None]] | None = None
    methods: list[Method] | Method | None = None
    solver: dict[Method, dict[str, Any]] | None = Field(
        None, description="estimator options per method, e.g. {dm-paper: {solver: cvxpy, tol: 1e-8, fallback: []}, "
                          "wls: {solver: cvxpy, cvxpy_solver: SCS}, ols: {solver: newton}}; solver: newton (dualid's "
                          "interior point) or cvxpy (the conic reference, with cvxpy_solver CLARABEL or SCS); "
                          "checked by the estimator")
    prior: PriorSection | str | None = None
    validation: ValidationSection | None = None
    references: dict[str, str] | None = None
    out: str | None = None
    uncertainty: UncertaintySection | None = None
    margin: MarginSection | float | None = Field(
        None, description="chart-invariant margin M_i(θ) ⪰ ε·M_i(θ_ref) on every method; a number: ε against a WLS pilot")


def json_schema() -> dict:
    """The JSON Schema of the config file."""
    schema = FitConfigSchema.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "dualid fit config"
    return schema


def check_shape(d: Any, where: str = "config") -> None:
    """ConfigError listing every mismatch with the schema by key path ('joint_terms.coulomb_velocity: …')."""
    try:
        FitConfigSchema.model_validate(d)
    except ValidationError as exc:
        best: dict[str, tuple[int, list[str]]] = {}  # top key -> (depth, messages): a union's most specific errors
        for e in exc.errors():
            parts = [str(p) for p in e["loc"] if not _is_union_tag(p)]
            path = ".".join(parts) or "(top level)"
            top = parts[0] if parts else path
            message = f"{path}: {e['msg']} (got {e.get('input')!r})"
            depth = len(e["loc"])
            if top not in best or depth > best[top][0]:
                best[top] = (depth, [message])
            elif depth == best[top][0] and message not in best[top][1]:
                best[top][1].append(message)
        raise ConfigError(f"{where}: " + "; ".join(m for _, ms in best.values() for m in ms)) from None


def _is_union_tag(part) -> bool:
    """Pydantic names the member of a union it tried ('str', 'ModelSection', 'list[...]') in error paths."""
    p = str(part)
    return not isinstance(part, int) and ("[" in p or p in ("str", "float", "int", "bool", "dict", "list", "none")
                                          or p.endswith(("Section", "Effort", "Topic")))
