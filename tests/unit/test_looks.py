"""coverage.looks: correlated looks give the beta-binomial's cumulative P_D, agree with a
direct integral of the comonotone model across size bins, reduce to the paper's product at
rho = 0; the viewpoint rule counts one look per viewpoint bin; merges, snapshots and
config errors."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, stats
from scipy.special import betaln

from pdcov.config.load import mission_from_dict
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.looks import (
    QUADRATURE,
    LooksConfig,
    LooksRule,
    ViewpointBins,
    beta_shape,
    detectability_quantile,
    pd_of_node_log_miss,
)
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.errors import ConfigError, InputFileError

PINHOLE = CameraModel(640, 480, np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]))
CORRELATED = LooksConfig(LooksRule.CORRELATED)


def model(p_detect, rho, edges=None):
    n = len(p_detect)
    edges = edges or [1.0, 2000.0] if n == 1 else edges
    return DetectorModel.from_dict({
        "version": 4, "bin_edges_px": list(edges), "p_detect": list(p_detect),
        "p_false_alarm": [0.05] * n, "fa_rate_per_mpx": [50.0] * n, "input_size_px": None,
        "looks": {"correlation": list(rho)}})


def of_ab(a, b):
    """(mean, rho) of Beta(a, b)."""
    return a / (a + b), 1.0 / (a + b + 1.0)


def grid(detector, half_m=6.0, looks=CORRELATED, **kw):
    dom = Domain.from_enu([[-half_m, -half_m], [half_m, -half_m], [half_m, half_m],
                           [-half_m, half_m]])
    g = dom.grid_geometry(1.0)
    return CoverageGrid(g, dom.free_mask(g), PINHOLE, detector, looks=looks, **kw)


def nadir(xyz=(0.0, 0.0, 10.0), t_s=float("nan")):
    return fixed_mount_pose(np.eye(3), xyz, FixedMount(pitch_rad=-math.pi / 2), t_s)


def beta_binomial_pd(a, b, n):
    return -math.expm1(betaln(a, b + n) - betaln(a, b))


@pytest.mark.parametrize("a,b", [(0.3, 2.0), (0.5, 0.5), (2.0, 3.0), (0.1, 0.9), (8.0, 1.5)])
def test_n_looks_in_one_bin_give_the_beta_binomial(a, b):
    mean, rho = of_ab(a, b)
    g = grid(model([mean], [rho]))
    centre = g.geometry.cell_of(0.3, 0.3)
    checks = {1, 2, 5, 20, 100, 1000}
    for n in range(1, 1001):
        g.update(nadir())
        if n in checks:
            assert g.n_obs[centre] == n
            assert g.pd[centre] == pytest.approx(beta_binomial_pd(a, b, n), abs=1e-3)
    # Every observed cell had the same 1000 looks.
    seen = g.n_obs == 1000
    assert seen.sum() > 50
    np.testing.assert_allclose(g.pd[seen], beta_binomial_pd(a, b, 1000), atol=1e-3)


@pytest.mark.parametrize("a,b", [(0.05, 0.05), (0.2, 5.0), (100.0, 0.05), (1.0, 100.0)])
@pytest.mark.parametrize("n", [1, 3, 30, 1000, 108_000])
def test_quadrature_matches_the_beta_binomial_at_extreme_shapes(a, b, n):
    mean, rho = of_ab(a, b)
    p = detectability_quantile(mean, rho, QUADRATURE.q)
    with np.errstate(divide="ignore"):
        nodes = n * np.log1p(-p)
    assert float(pd_of_node_log_miss(nodes)) == pytest.approx(beta_binomial_pd(a, b, n),
                                                               abs=2e-4)


def test_looks_in_two_bins_match_a_direct_integral_and_monte_carlo():
    (m1, r1), (m2, r2) = of_ab(0.4, 1.2), of_ab(3.0, 2.0)
    det = model([m1, m2], [r1, r2], edges=[1.0, 30.0, 2000.0])
    g = grid(det)
    for _ in range(7):  # 10 m: a 1 m cell is 50 px, bin 2
        g.update(nadir((0.0, 0.0, 10.0)))
    for _ in range(12):  # 25 m: 20 px, bin 1
        g.update(nadir((0.0, 0.0, 25.0)))
    cell = g.geometry.cell_of(0.3, 0.3)
    (a1, b1), (a2, b2) = beta_shape(m1, r1), beta_shape(m2, r2)

    def miss(q):
        return ((1 - stats.beta.ppf(q, a1, b1)) ** 12) * ((1 - stats.beta.ppf(q, a2, b2)) ** 7)

    direct = 1.0 - integrate.quad(miss, 0.0, 1.0, limit=400, epsabs=1e-12)[0]
    assert g.pd[cell] == pytest.approx(direct, abs=1e-4)
    # Monte Carlo of the generative model: a person's q, then Bernoulli looks.
    rng = np.random.default_rng(3)
    q = rng.random(200_000)
    p1, p2 = stats.beta.ppf(q, a1, b1), stats.beta.ppf(q, a2, b2)
    found = (rng.binomial(12, p1) + rng.binomial(7, p2)) > 0
    se = math.sqrt(direct * (1 - direct) / len(q))
    assert abs(found.mean() - g.pd[cell]) < 4 * se
    # The comonotone person is found less often than independent looks predict.
    independent = 1 - (1 - m1) ** 12 * (1 - m2) ** 7
    assert g.pd[cell] < independent - 0.02


def test_rho_zero_is_the_independent_grid():
    p = [0.1, 0.4, 0.6, 0.3]
    edges = [1, 20, 40, 80, 2000]
    correlated = grid(model(p, [0.0] * 4, edges), half_m=20)
    independent = grid(model(p, [0.0] * 4, edges), half_m=20, looks=None)
    for k in range(60):
        pose = nadir((0.3 * k - 9, 0.1 * k, 8.0 + 0.5 * k))
        correlated.update(pose)
        independent.update(pose)
    assert (independent.pd > 0).sum() > 400
    np.testing.assert_allclose(correlated.pd, independent.pd, rtol=2e-6, atol=1e-7)
    np.testing.assert_array_equal(correlated.pfa, independent.pfa)
    np.testing.assert_array_equal(correlated.n_obs, independent.n_obs)


def test_correlated_grids_merge_in_any_order_and_survive_snapshots(tmp_path):
    det = model(*zip(of_ab(0.5, 2.0), of_ab(2.0, 1.0), strict=True), edges=[1, 30, 2000])
    poses = [nadir((0.4 * k - 4, 0.2 * k - 2, 9.0 + k)) for k in range(20)]
    one = grid(det, half_m=12)
    for p in poses:
        one.update(p)
    a, b = grid(det, half_m=12), grid(det, half_m=12)
    for k, p in enumerate(poses):
        (a if k % 3 else b).update(p)
    b.merge(a)
    np.testing.assert_array_equal(b.pd, one.pd)
    one.save_npz(tmp_path / "g.npz")
    again = CoverageGrid.load_npz(tmp_path / "g.npz", PINHOLE, det, looks=CORRELATED)
    np.testing.assert_array_equal(again.pd, one.pd)
    np.testing.assert_array_equal(again.log_miss_nodes(), one.log_miss_nodes())
    with pytest.raises(InputFileError, match="coverage.looks: correlated, the mission says "
                                             "independent"):
        CoverageGrid.load_npz(tmp_path / "g.npz", PINHOLE, det)


def test_other_detectors_refuse_to_merge_but_combine_at_the_nodes():
    visible = model(*zip(of_ab(0.5, 1.5), strict=True))
    thermal = model(*zip(of_ab(2.0, 2.0), strict=True))
    a, b = grid(visible), grid(thermal)
    for _ in range(3):
        a.update(nadir())
    for _ in range(4):
        b.update(nadir())
    with pytest.raises(ValueError, match="different detector models.*quadrature nodes"):
        a.merge(b)
    with pytest.raises(ValueError, match="coverage.looks independent into one of "
                                         "correlated"):
        a.merge(grid(visible, looks=None))
    cell = a.geometry.cell_of(0.3, 0.3)
    both = pd_of_node_log_miss(a.log_miss_nodes() + b.log_miss_nodes())[cell]
    (a1, b1), (a2, b2) = beta_shape(*of_ab(0.5, 1.5)), beta_shape(*of_ab(2.0, 2.0))
    direct = 1 - integrate.quad(lambda q: (1 - stats.beta.ppf(q, a1, b1)) ** 3
                                * (1 - stats.beta.ppf(q, a2, b2)) ** 4, 0, 1, limit=200)[0]
    assert both == pytest.approx(direct, abs=1e-4)
    # An independent grid's node log-misses are its log-miss at every node.
    ind = grid(visible, looks=None)
    ind.update(nadir())
    np.testing.assert_allclose(pd_of_node_log_miss(ind.log_miss_nodes()), ind.pd, atol=1e-12)


def test_viewpoint_counts_the_best_look_per_direction():
    det = model([0.2, 0.5], [0.0, 0.0], edges=[1, 30, 2000])
    bins = ViewpointBins(azimuth_bins=4, elevation_bins=6)  # 15 deg; the cap above 75
    g = grid(det, half_m=30, looks=LooksConfig(LooksRule.VIEWPOINT, bins))
    cell = g.geometry.cell_of(0.3, 0.3)
    # Straight above: the cap; 10 m (50 px, bin 2) and 25 m (20 px, bin 1).
    for _ in range(5):
        g.update(nadir((0.0, 0.0, 25.0)))
    assert g.pd[cell] == pytest.approx(0.2, abs=1e-6)
    g.update(nadir((0.0, 0.0, 10.0)))
    assert g.pd[cell] == pytest.approx(0.5, abs=1e-6)  # the better look replaces it
    g.update(nadir((0.0, 0.0, 25.0)))
    assert g.pd[cell] == pytest.approx(0.5, abs=1e-6)  # order does not matter
    # From the north-east, 67 deg up: another viewpoint bin, an independent best look.
    assert bins.bin_of(np.array([3.0]), np.array([3.0]), np.array([10.0]))[0] == 16
    g.update(nadir((3.5, 3.5, 10.0)))
    assert g.pd[cell] == pytest.approx(1 - 0.5 * 0.5, abs=1e-6)
    g.update(nadir((3.6, 3.3, 10.0)))  # nearly the same direction: counts once
    assert g.pd[cell] == pytest.approx(1 - 0.5 * 0.5, abs=1e-6)
    assert g.n_obs[cell] == 9
    # Bins: azimuth from north through east, the cap at the top elevation bin.
    assert bins.bin_of(np.array([10.0]), np.array([0.0]), np.array([5.0]))[0] == 4 + 1
    assert bins.bin_of(np.array([-10.0]), np.array([0.1]), np.array([0.0]))[0] == 3
    assert bins.bin_of(np.array([0.0]), np.array([0.1]), np.array([10.0]))[0] == 20


def test_config_chooses_the_rule_and_names_bad_values():
    base = {"origin": {"lat_deg": 47.0, "lon_deg": 8.0, "ground_alt_msl_m": 400.0},
            "domain": {"polygon_enu_m": [[0, 0], [10, 0], [10, 10], [0, 10]],
                       "cell_size_m": 1.0},
            "camera": {"width_px": 640, "height_px": 480,
                       "K": [[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]],
                       "frame_rate_hz": 5},
            "detector": model(*zip(of_ab(1.0, 2.0), strict=True)).to_dict()}
    m = mission_from_dict(dict(base, coverage={"looks": "correlated", "min_revisit_s": 1}))
    assert m.looks.rule is LooksRule.CORRELATED and m.new_mission_grid().looks == m.looks
    assert mission_from_dict(base).new_mission_grid().looks.rule is LooksRule.INDEPENDENT
    v = mission_from_dict(dict(base, coverage={"looks": "viewpoint",
                                               "viewpoint": {"azimuth_bins": 6}}))
    assert v.looks.viewpoint == ViewpointBins(6, 3)
    for cov, match in (({"looks": "sometimes"}, "coverage.looks: expected one of"),
                       ({"viewpoint": {"azimuth_bins": 6}}, "only used with"),
                       ({"looks": "viewpoint", "viewpoint": {"azimuth_bins": 0}},
                        "azimuth_bins: expected an integer in 1..64")):
        with pytest.raises(ConfigError, match=match):
            mission_from_dict(dict(base, coverage=cov), source="m.yaml")
    with pytest.raises(ConfigError, match="m.yaml: coverage.looks: correlated needs the "
                                          "detector model's looks section"):
        mission_from_dict(dict(base, detector="illustrative", coverage={"looks": "correlated"}),
                          source="m.yaml")


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(6, 40)),
                min_size=1, max_size=8),
       st.floats(0.05, 0.95), st.floats(0.0, 0.9))
def test_correlated_pd_stays_in_range_and_never_decreases(frames, mean, rho):
    g = grid(model([mean, 0.5 * mean], [rho, 0.5 * rho], edges=[1, 30, 2000]))
    before = g.pd
    for xyz in frames:
        g.update(nadir(xyz))
        now = g.pd
        assert ((now >= 0) & (now <= 1)).all()
        assert (now >= before - 1e-7).all()
        before = now


@pytest.mark.parametrize("rule", [LooksRule.CORRELATED, LooksRule.VIEWPOINT])
def test_daemon_checkpoint_resumes_the_looks_and_a_changed_rule_starts_fresh(tmp_path, rule):
    from pdcov.service.checkpoint import CHECKPOINT_NAME, resume, write_checkpoint
    from pdcov.service.checkpoint_meta import CheckpointMeta

    det = model(*zip(of_ab(0.5, 2.0), of_ab(2.0, 1.0), strict=True), edges=[1, 30, 2000])
    looks = LooksConfig(rule, ViewpointBins(4, 3))
    flown = grid(det, half_m=12, looks=looks)
    poses = [nadir((0.5 * k - 5, 0.3 * k - 3, 6.0 + 0.7 * k)) for k in range(25)]
    for p in poses[:15]:
        flown.update(p)
    state = tmp_path / "state"
    state.mkdir()
    write_checkpoint(state / CHECKPOINT_NAME, flown, CheckpointMeta("h", "uav1"))
    r = resume(state, "h", grid(det, half_m=12, looks=looks))
    assert r.grid is not None, r.message
    # Resumed, then the rest of the flight: the grid of the whole flight, bit for bit,
    # and two halves merged in either order give it too.
    whole = grid(det, half_m=12, looks=looks)
    later = grid(det, half_m=12, looks=looks)
    for p in poses:
        whole.update(p)
    for p in poses[15:]:
        r.grid.update(p)
        later.update(p)
    np.testing.assert_array_equal(r.grid.pd, whole.pd)
    later.merge(flown)
    np.testing.assert_array_equal(later.pd, whole.pd)
    assert (whole.pd > 0).sum() > 100
    # Another rule: the checkpoint cannot be read as it, and is set aside.
    other = grid(det, half_m=12, looks=None)
    r = resume(state, "h", other)
    assert r.grid is None and r.set_aside is not None
    assert f"coverage.looks: {rule}, the mission says independent" in r.message


def test_correlated_looks_count_blur_rows_as_their_own_bins():
    """With blur bins the kernel's table index is (blur row, size bin): a blurred look
    takes its row's mean. At rho = 0 the grid is the independent blurred one; at rho > 0 a
    cell's n looks, all in one (blur, size) bin, give that bin's beta-binomial."""
    from pdcov.core.blur import BlurEffect

    p = [0.1, 0.4, 0.6, 0.3]
    edges = [1, 20, 40, 80, 2000]
    doc = {"version": 4, "bin_edges_px": edges, "p_detect": p, "p_false_alarm": [0.05] * 4,
           "fa_rate_per_mpx": [50.0] * 4, "input_size_px": None,
           "blur": {"edges_px": [0.0, 1.0, 3.0, 64.0],
                    "p_detect": [[0.1, 0.4, 0.6, 0.3], [0.05, 0.3, 0.5, 0.2],
                                 [0.02, 0.1, 0.2, 0.1]],
                    "p_false_alarm": [[0.05] * 4] * 3}}
    # 500 px * 4 m/s * 0.01 s / 10 m = 2 px: blur bin [1, 3), the second row.
    moving = fixed_mount_pose(np.eye(3), (0.5, 0.5, 10.0), FixedMount(pitch_rad=-math.pi / 2))
    moving = type(moving)(moving.R_enu_cam, moving.r_cam_enu, 0.0,
                          v_cam_enu_m_s=np.array([4.0, 0.0, 0.0]), omega_enu_rad_s=np.zeros(3))
    for rho in (0.0, 0.3):
        det = DetectorModel.from_dict({**doc, "looks": {"correlation": [rho] * 4}})
        corr = grid(det, half_m=20, exposure_s=0.01)
        indep = grid(det, half_m=20, looks=None, exposure_s=0.01)
        n = 12
        for _ in range(n):
            corr.update(moving)
            indep.update(moving)
        assert corr.blur_effect is BlurEffect.APPLIED
        np.testing.assert_array_equal(corr.pfa, indep.pfa)
        r, c = 20, 20  # under the camera: 50 px, size bin [40, 80) = 3rd; blur row 2
        if rho == 0.0:
            np.testing.assert_allclose(corr.pd, indep.pd, rtol=2e-6, atol=1e-7)
            assert indep.pd[r, c] == pytest.approx(1 - 0.5 ** n, rel=1e-6)
        else:
            a, b = beta_shape(0.5, rho)
            expect = 1.0 - math.exp(betaln(a, b + n) - betaln(a, b))
            assert corr.pd[r, c] == pytest.approx(expect, abs=1e-3)
            assert corr.pd[r, c] < indep.pd[r, c] - 0.05
