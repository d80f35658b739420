"""``python -m benchmarks.reliability``: the daemon's faults end to end, with real processes
(issue 15, part A). Each scenario runs ``pdcov-sitl fly`` (JSBSim, MAVLink over UDP),
``pdcov serve`` and a Zenoh router in this process, and the ground watcher's own shell
(``ground.live.WatchShell`` with ``ground.watcher.Watcher``) in a thread of this process:

* **soak**: a long flight at high speed with random link and autopilot faults; the daemon's
  resident memory sampled over simulated time; the final grid (checkpoint written at
  SIGTERM) equals ``pdcov evaluate`` of the daemon's own recording cell for cell, the
  watcher's grid equals it too, and the frames used are compared with ``pdcov evaluate`` of
  the simulator's own tlog (what was sent before the link faults);
* **crash**: ``kill -9`` with a checkpoint every ``period`` s, every other kill aimed at a
  checkpoint write (the moment its temporary file appears; the file is left behind, empty or
  part-written) and the others at random moments; every restart resumes a valid checkpoint
  holding every frame some status had reported ``period`` + 0.5 s before the kill;
* **router**: the Zenoh router gone for ``outage`` s mid-flight, then back on the same port;
  the watcher (never restarted) ends with the daemon's exact final grid;
* **disk**: the state directory on a small tmpfs, filled up mid-flight: the daemon keeps
  computing and publishing, says so in its status (``checkpoint.error``,
  ``recording_error``, ``faults.checkpoint_errors``), and checkpoints again when space is
  freed. Needs root (mount); skipped with the reason otherwise.

``--write-docs`` runs the documented sizes (a 2-hour soak, 50 kills, a 60 s router outage)
plus the fuzz properties with many examples, and writes docs/reliability.md; ``--quick``
runs the CI sizes (tests/simulators/test_reliability.py uses the functions directly).

Modules: ``rig`` (mission, plan, ports, command lines, the watcher thread), one per scenario
(``soak``, ``crash``, ``outages``: router and disk), ``doc_block`` (fuzz figures, the
docs/reliability.md block) and ``__main__`` (the command line).
"""
