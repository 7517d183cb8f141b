"""Scenarios: YAML experiments checked by their kind's pydantic model, their runner, results and reports (the bench
side)."""
