"""Trajectory optimisation through contact on the flow's B-derivative (placeholder)."""
