"""The real-robot workflow: a URDF and logs in; identified parameters, a URDF, validation and a report out.

- ``config``: ``FitConfig`` (YAML or dict; every CLI option can live in it).
- ``fit``: ``fit_robot(config) -> FitOutcome`` (load, preprocess, model, identifiability, fits, validation).
- ``validate``: predicted vs measured effort (inverse dynamics) and accelerations (forward dynamics).
- ``report``: parameters.yaml/json, <method>.urdf, report.md and PNGs (the matplotlib leaf).
- ``dfki``: the DFKI double pendulum lab's reference parameters as our θ.
"""

from dualid.workflow.config import FitConfig
from dualid.workflow.fit import FitOutcome, MethodFit, fit_robot

__all__ = ["FitConfig", "FitOutcome", "MethodFit", "fit_robot"]
