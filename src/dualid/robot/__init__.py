"""The real-robot workflow: a URDF and logs in; identified parameters, validation and a URDF out.

- ``config``: ``FitConfig`` (YAML or dict; every CLI option can live in it).
- ``fit``: ``fit_robot(config) -> FitOutcome`` (load, preprocess, model, identifiability, fits, validation).
- ``validate``: validation of a URDF against logs.
- ``dfki``: the DFKI double pendulum lab's reference parameters as our θ.
"""
