"""Scenarios: schema-validated YAML experiments, their runner, results and reports (the bench side)."""
