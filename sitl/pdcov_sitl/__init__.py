"""pdcov-sitl: a JSBSim F450 quadcopter that flies pdcov plans and speaks MAVLink like an
ArduPilot or PX4 autopilot (docs/simulator.md). It may import pdcov; pdcov never imports
it."""

__version__ = "0.1.0"
