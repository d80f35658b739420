"""Coverage planning: decomposition, patterns, plan files, flight kinematics, predicted coverage,
Pareto search and gap re-fly."""
