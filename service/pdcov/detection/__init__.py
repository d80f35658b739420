"""Detector statistics from labelled test sets: readers, matching and binning, figures."""
