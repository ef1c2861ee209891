"""The solver benchmark: the dual-metric solvers (Newton, SDP) and constrained OLS against N."""
