"""The grid's update window does not grow with the domain (a large domain, timed)."""

from tests.support.square_grid import pose, square_grid


def test_window_does_not_grow_with_the_domain():
    small, big = square_grid(half_m=50), square_grid(half_m=5000)
    p = pose(xyz=(0, 0, 10))
    (r0, r1, c0, c1), (R0, R1, C0, C1) = (small._view.window(small._base, p)[0],
                                        big._view.window(big._base, p)[0])
    assert (r1 - r0, c1 - c0) == (R1 - R0, C1 - C0)
