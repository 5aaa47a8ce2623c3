"""Sensor measurement models (one module per model)."""
