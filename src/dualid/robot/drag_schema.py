"""The ``model.drag`` section of the fit config's JSON Schema (``dualid.robot.schema``); the values are
checked by ``dualid.model.drag_spec.DragSpec.from_dict``."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class DragBodySection(BaseModel):
    model_config = ConfigDict(extra="forbid")

    frame: str | None = Field(None, description="a frame of the model (URDF link or joint, chain link<i>); "
                                                "default: the body's name")
    diagonal: int | list[float] | None = Field(
        None, description="3 (vx, vy, wz) or 6 (vx, vy, vz, wx, wy, wz) coefficients, or their nominal values")
    full: int | list[list[float]] | None = Field(
        None, description="a full PSD drag matrix over 3 or 6 components, or its nominal value")
    xyz: list[float] | None = Field(None, min_length=3, max_length=3, description="drag frame offset [m]")
    rpy: list[float] | None = Field(None, min_length=3, max_length=3, description="drag frame rotation [rad]")


class DragSection(BaseModel):
    model_config = ConfigDict(extra="forbid")

    base: Literal["fixed", "planar"] = Field("fixed", description="root joint: fixed, or planar (x, y, theta)")
    chain: list[float] | None = Field(None, description="instead of a URDF: a planar chain of these link lengths [m]")
    bodies: dict[str, DragBodySection] = Field(description="body name -> its drag frame and form")
    damping: list[str] | dict[str, float | None] | str | None = Field(
        None, description="damped joints, or {joint: nominal damping}")
