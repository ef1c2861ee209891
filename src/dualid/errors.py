"""Exceptions raised by dualid. Every message names what was expected and what was received."""


class DualidError(Exception):
    """Base class of dualid's errors."""


class DataError(DualidError, ValueError):
    """Input data with wrong shapes, non-finite values, missing columns or inconsistent units."""


class IdentifiabilityError(DualidError):
    """The regressor does not determine the parameters (too few samples or rank deficiency)."""


class ConsistencyError(DualidError, ValueError):
    """A parameter vector (e.g. a nominal θ₀) is not physically consistent."""


class MetricError(DualidError):
    """The metric M_i(θ) is not (or cannot be made) positive definite where it must be."""


class SolverError(DualidError):
    """A numerical solver failed; the message carries its status."""

    def __init__(self, message: str, status: str | None = None):
        super().__init__(message)
        self.status = status


class ConfigError(DualidError, ValueError):
    """A configuration (file, mapping or hyperparameter) that cannot be used as given; the message
    names the key path, what was expected and what was received."""


class OutputError(DualidError, OSError):
    """An output file or directory that cannot be written under dualid's output policy."""


class ModelError(DualidError, ValueError):
    """A model that cannot be built or used as given: a URDF, a parameter space, a metric, a joint
    selection; the message names the file, body or joint."""


class MissingFileError(DataError, FileNotFoundError):
    """An input file (log, URDF, config, data set part) that does not exist; the message names it."""


class SimulationError(DualidError, RuntimeError):
    """A simulator (the paper's systems) failed: an integrator diverged or the state left its range."""


class SolverOptionError(ConfigError):
    """An estimator's solver, tolerance, iteration limit or fallback chain is not one it accepts."""


class DualidWarning(UserWarning):
    """Something in the input that is probably wrong but not certainly (e.g. a logged velocity far
    from dq/dt, the same log for training and testing); the fit goes on and the report records it."""


class OptimumAtInfinityWarning(DualidWarning):
    """The objective's infimum is approached as θ grows without bound: the returned θ̂ is where the solver
    stopped on that ray, not a minimiser (``result.info["optimum_at_infinity"]``)."""


class PlausibleWarning(DualidWarning):
    """The plausible-parameter step of a fit failed (the model files then carry the raw fit θ̂) or found no point
    inside the fit's confidence region; the run goes on, and the report, parameters.yaml and the exit code say so."""


class ModelFileWarning(DualidWarning):
    """A method's model files were not written: the parameters they would carry are not physical (e.g. a link
    heavier than twice the prior's whole moving mass); parameters.yaml keeps the values, the report says why."""


class SolverOutputWarning(UserWarning):
    """A line a compiled solver printed to standard output (``estimators.base.solver_stdout``), re-issued as a
    warning so that the estimator records it (``solver_warnings``) instead of the terminal showing it raw."""
