"""Readers of the file formats of labelled test sets and detector outputs (one module per
format; ``detection.annotations`` chooses among them), each into a ``TruthSet`` and
``Boxes`` (detection/truth_set.py)."""
