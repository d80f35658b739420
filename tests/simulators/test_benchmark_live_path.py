"""benchmarks.live_path at its tiny CI size: the three recordings are made (the simulator
flies twice), replayed through the daemon's decisions and evaluated offline, and the live
grids equal the offline ones cell for cell (main exits 1 otherwise). No timing is asserted."""


from benchmarks.live_path import main


def test_smoke_run_live_equals_offline(capsys):
    assert main(["--smoke"]) == 0
    out = capsys.readouterr().out
    for name in ("gimbal", "fixed", "S1"):
        assert f"| {name} | live grid = offline grid | equal | cell for cell | pass |" in out
        assert f"| {name} | live (daemon decisions): CPU ms/frame |" in out
    assert "DIFFERENT" not in out
