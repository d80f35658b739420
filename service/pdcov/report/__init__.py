"""Evaluation outputs: metrics, figures, GIS exports."""
