"""The state estimator."""
