"""Studies that reproduce the paper's experiments on simulated systems."""

from dualid.studies.reproduce import DEFAULT_METHODS, FitRecord, StudyResult, Summary, reproduce, run_study

__all__ = ["DEFAULT_METHODS", "FitRecord", "StudyResult", "Summary", "reproduce", "run_study"]
