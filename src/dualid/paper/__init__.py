"""The paper's experiments on simulated systems: fit every method, predict the test runs, score."""
