"""The flight engine's parts, with no I/O: each camera's frames (``camera_frames``), where
frames fall and when each is decided (``frame_schedule``), the ENU origin's ground altitude
(``ground_altitude``). The daemon (service/coverage.py) drives them from the link; every
``now_s`` / ``t_s`` is passed in (the autopilot clock, s)."""
