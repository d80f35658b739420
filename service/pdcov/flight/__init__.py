"""The flight engine's frames, with no I/O: the one frame decision (``frame_decision``, with
``frame_selection``), the ENU origin's ground altitude (``ground_altitude``), and its two
per-camera drivers: the daemon's (``camera_frames``, with ``frame_schedule``: where frames
fall and when each is decided), driven from the link by service/coverage.py, and
``pdcov evaluate``'s (``log_frames``), driven from a whole log. Every ``now_s`` / ``t_s``
is passed in (the autopilot clock, s)."""
