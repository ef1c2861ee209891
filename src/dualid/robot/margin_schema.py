"""The ``margin`` section of the fit config's schema (see robot/margin_config.py for its values)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class MarginSection(BaseModel):
    model_config = ConfigDict(extra="forbid")

    epsilon: float = Field(ge=0, lt=1, description="ε of M_i(θ) ⪰ ε·M_i(θ_ref) at every configuration "
                                                   "(per body: C_b(θ) ⪰ ε·C_b(θ_ref)); off when the section is absent")
    reference: Literal["wls", "prior"] = Field("wls", description="θ_ref: a constrained WLS pilot or the prior")
