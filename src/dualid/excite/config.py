"""``ExciteConfig``: the settings of an excitation design, from ``excite.yaml`` or a dict (pydantic).

YAML form (every key optional)::

    period: 10.0          # [s] one period of the base frequency; the trajectory lasts one period
    harmonics: 5          # K
    criterion: dm         # dm, logdet or cond (docs/excite.md says why dm is the default)
    start: {Joint1: 0.0}  # rest configuration [rad or m]; default: mid-range of finite limits, else 0
    grid: 100             # samples per period where the criterion and the constraints are evaluated
    rate: 200             # [Hz] of the written trajectory CSV
    check_rate: 1000      # [Hz] of the final limit check
    limits:               # per joint, overriding the URDF's (lower, upper [rad], velocity [rad/s],
      Joint1: {velocity: 5, acceleration: 20, effort: 4}   # acceleration [rad/s²], effort [N m])
    acceleration: null    # [rad/s²] for every joint the URDF cannot give it to (URDF has no such field)
    joint_terms: {viscous: true, coulomb: true, armature: true, coulomb_velocity: 0.01}
    min_distance: null    # [m] between non-adjacent links, only if the URDF has collision geometry
    torque_noise: 0.1     # [N m] σ of the torque noise for the predicted standard errors (or {joint: σ})
    restarts: 4
    seed: 0
    maxiter: 100          # SLSQP iterations per restart
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from dualid.errors import ConfigError

Criterion = Literal["dm", "logdet", "cond"]
CRITERIA: tuple[str, ...] = ("dm", "logdet", "cond")


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class JointLimits(_Section):
    lower: float | None = None  # [rad or m]
    upper: float | None = None
    velocity: float | None = Field(None, gt=0)  # [rad/s or m/s]
    acceleration: float | None = Field(None, gt=0)  # [rad/s² or m/s²]
    effort: float | None = Field(None, gt=0)  # [N m or N]


class JointTerms(_Section):
    viscous: bool = True
    coulomb: bool = True
    armature: bool = True
    coulomb_velocity: float = Field(0.01, gt=0)  # [rad/s]


class ExciteConfig(_Section):
    """An excitation design (see the module docstring)."""

    period: float = Field(10.0, gt=0)
    harmonics: int = Field(5, ge=2, le=30)
    criterion: Criterion = "dm"
    start: dict[str, float] = Field(default_factory=dict)
    grid: int = Field(100, ge=10)
    rate: float = Field(200.0, gt=0)
    check_rate: float = Field(1000.0, gt=0)
    limits: dict[str, JointLimits] = Field(default_factory=dict)
    acceleration: float | None = Field(None, gt=0)
    joint_terms: JointTerms | None = Field(default_factory=JointTerms)
    min_distance: float | None = Field(None, ge=0)
    torque_noise: float | dict[str, float] = 0.1
    restarts: int = Field(4, ge=1)
    seed: int = 0
    maxiter: int = Field(100, ge=1)

    @classmethod
    def from_dict(cls, d, where: str = "excite config") -> "ExciteConfig":
        """The config of a mapping; ConfigError naming every bad key path."""
        if d is None:
            d = {}
        if not isinstance(d, dict):
            raise ConfigError(f"{where}: expected a mapping of settings, got {type(d).__name__} {d!r}")
        try:
            return cls.model_validate(d)
        except ValidationError as exc:
            parts = []
            for e in exc.errors():
                path = ".".join(str(p) for p in e["loc"] if not str(p).startswith(("float", "dict"))) or "(top level)"
                parts.append(f"{path}: {e['msg']} (got {e.get('input')!r})")
            raise ConfigError(f"{where}: " + "; ".join(dict.fromkeys(parts))) from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> "ExciteConfig":
        from dualid.data.files import read_mapping

        return cls.from_dict(read_mapping(path, "excite config"), where=f"excite config {path}")

    def with_overrides(self, **changes) -> "ExciteConfig":
        """A copy with the given (not None) settings changed, checked again."""
        d = self.model_dump()
        d.update({k: v for k, v in changes.items() if v is not None})
        return ExciteConfig.from_dict(d)
