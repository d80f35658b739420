"""`python -m benchmarks --smoke` runs every step at its tiny size (simulator flights
included) and writes its report (tests/slow/test_benchmarks_smoke.py: the references)."""

from benchmarks.__main__ import (
    SMOKE,
    main,
)


def test_smoke_run_completes(capsys):
    assert main(["--smoke", "--scenarios", "S1", "S2", "S5"]) == 0
    out = capsys.readouterr().out
    for figure in ("update: frames/s", "floor passes", "R1 / pdcov", "R2 vs pdcov grid",
                   "offline evaluate (tlog)", "planner: plans/min",
                   "update with the DEM / flat S1", "R3 / pdcov with the DEM",
                   "R3 vs flat pdcov grid", "R3 vs pdcov grid with the DEM"):
        assert figure in out
    assert f"{SMOKE.r1_frames} frames" in out
