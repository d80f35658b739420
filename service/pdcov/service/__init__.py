"""The onboard daemon (`pdcov serve`): link, frame clock, checkpoints, publishing."""
