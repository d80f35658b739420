"""The MAVLink edge: messages and logs become telemetry samples, the PoseTracker turns them into
camera poses; autopilot parameters, gimbal report interpretation and mission upload."""
