"""C-functions: the defining identity and generalized Jacobians vs finite differences."""
import numpy as np
import pytest

from ngcontact.algebra.cfunctions import FischerBurmeister, MinFunction, get_cfunction

CFS = [MinFunction(), FischerBurmeister()]


@pytest.mark.parametrize("cf", CFS, ids=lambda c: c.name)
def test_zero_iff_complementarity(cf):
    rng = np.random.default_rng(0)
    a = rng.normal(size=2000)
    b = rng.normal(size=2000)
    # complementary pairs: one zero, the other >= 0
    a[:500], b[:500] = 0.0, np.abs(b[:500])
    a[500:1000], b[500:1000] = np.abs(a[500:1000]), 0.0
    comp = (a >= 0) & (b >= 0) & (a * b == 0)
    phi = cf.value(a, b)
    assert np.all(np.abs(phi[comp]) < 1e-15)
    assert np.all(np.abs(phi[~comp]) > 0)


@pytest.mark.parametrize("cf", CFS, ids=lambda c: c.name)
def test_jacobian_matches_finite_differences(cf):
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=500), rng.normal(size=500)
    keep = (np.abs(a - b) > 1e-3) & (np.hypot(a, b) > 1e-3)  # away from the kinks
    a, b = a[keep], b[keep]
    da, db = cf.jacobian(a, b)
    eps = 1e-7
    fd_a = (cf.value(a + eps, b) - cf.value(a - eps, b)) / (2 * eps)
    fd_b = (cf.value(a, b + eps) - cf.value(a, b - eps)) / (2 * eps)
    np.testing.assert_allclose(da, fd_a, atol=1e-7)
    np.testing.assert_allclose(db, fd_b, atol=1e-7)


def test_jacobians_at_kinks_are_generalized_jacobian_elements():
    da, db = MinFunction().jacobian(np.array([0.0, 1.0]), np.array([0.0, 1.0]))
    assert da.tolist() == [1.0, 1.0] and db.tolist() == [0.0, 0.0]  # tie -> the gap is selected
    da, db = FischerBurmeister().jacobian(np.array([0.0]), np.array([0.0]))
    # Clarke Jacobian of FB at 0: {(xi - 1, zeta - 1): xi^2 + zeta^2 <= 1}
    assert (da[0] + 1) ** 2 + (db[0] + 1) ** 2 <= 1 + 1e-15
    assert da[0] < 0 and db[0] < 0


def test_fb_jacobian_signs_keep_reduced_system_spd():
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=1000), rng.normal(size=1000)
    da, db = FischerBurmeister().jacobian(a, b)
    assert np.all(da <= 0) and np.all(db <= 0) and np.all(da + db < 0)


def test_get_cfunction_by_name_and_error():
    assert get_cfunction("min").name == "min"
    assert get_cfunction("fb").name == "fb"
    with pytest.raises(ValueError, match="cfun"):
        get_cfunction("max")


@pytest.mark.parametrize("cf", CFS, ids=lambda c: c.name)
def test_row_classes_solve_the_linearized_rows(cf):
    """classify_rows: any (g', y') that meets the prescriptions of the row classes satisfies the
    linearized rows C + Ca (g' - g) + Cb (y' - y) = 0 (the reduction every Newton step relies on)."""
    from ngcontact.algebra.system import classify_rows

    rng = np.random.default_rng(3)
    g, y = rng.normal(size=400), rng.normal(size=400)
    g[:50], y[50:100] = 0.0, 0.0  # kinks of min (tie) and FB
    C, (Ca, Cb) = cf.value(g, y), cf.jacobian(g, y)
    rc = classify_rows(g, y, C, Ca, Cb)
    assert np.array_equal(rc.eq | rc.fixed | rc.mixed, np.ones(400, bool))
    assert not (rc.eq & rc.fixed).any() and not (rc.eq & rc.mixed).any() and not (rc.fixed & rc.mixed).any()
    if cf.name == "min":
        assert np.array_equal(rc.eq, g <= y) and not rc.mixed.any()
    else:
        assert rc.mixed.sum() > 300 and np.all(rc.w[rc.mixed] >= 0)
    g_new, y_new = rng.normal(size=400), rng.normal(size=400)
    g_new[rc.eq] = rc.g_target[rc.eq]
    y_new[rc.fixed] = rc.y_fixed[rc.fixed]
    y_new[rc.mixed] = rc.c0[rc.mixed] - rc.w[rc.mixed] * g_new[rc.mixed]
    lin = C + Ca * (g_new - g) + Cb * (y_new - y)
    assert np.abs(lin).max() <= 1e-12 * (1 + np.abs(C).max() + np.abs(y_new).max() + np.abs(g_new).max())
