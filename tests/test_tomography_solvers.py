"""The solvers and weights of vehicle.tomography, against their definitions."""

import numpy as np
import scipy.sparse as sp

from vehicle.tomography.solvers import (
    RegularisedLS,
    gradient_operators,
    sparse_nonnegative,
    tv_objective,
    tv_solve,
)
from vehicle.tomography.weights import LINE_CUT, LINE_WIDTH, Grid, WeightCache, weight_rows


def small_problem(seed=0, links=30):
    rng = np.random.default_rng(seed)
    grid = Grid((0.0, 0.0, 2.0, 1.5), 0.25)
    W = sp.csr_matrix(rng.random((links, grid.nx * grid.ny)) * (rng.random((links, grid.nx * grid.ny)) < 0.2))
    return grid, W, rng


def test_the_linear_map_is_the_regularised_least_squares_solution():
    grid, W, rng = small_problem()
    centres, delta, alpha = grid.centres(), 0.5, 0.3
    y = rng.normal(size=W.shape[0])
    C = np.exp(-np.linalg.norm(centres[:, None] - centres[None], axis=2) / delta)
    Wd = W.toarray()
    direct = np.linalg.solve(Wd.T @ Wd + alpha * np.linalg.inv(C), Wd.T @ y)
    lmap = RegularisedLS(W, centres, delta)
    assert np.allclose(lmap.solve(y, alpha), direct, atol=1e-6)


def test_leave_one_out_residuals_are_what_the_other_links_predict():
    grid, W, rng = small_problem(1)
    y = rng.normal(size=W.shape[0])
    lmap = RegularisedLS(W, grid.centres(), 0.5)
    loo = lmap.loo_residuals(y, 0.2)
    for i in (0, 7):
        keep = np.arange(W.shape[0]) != i
        x = RegularisedLS(W[keep], grid.centres(), 0.5).solve(y[keep], 0.2)
        assert np.isclose(loo[i], y[i] - W[i] @ x, atol=1e-6)


def test_gcv_chooses_an_alpha_near_the_best_one():
    """On images drawn from the prior, the image error at GCV's alpha is within 30 % of the best alpha's."""
    grid, W, rng = small_problem(2, links=40)
    centres = grid.centres()
    C = np.exp(-np.linalg.norm(centres[:, None] - centres[None], axis=2) / 0.5)
    truth = np.linalg.cholesky(C + 1e-9 * np.eye(len(C))) @ rng.normal(size=len(C))
    y = W @ truth + rng.normal(0, 1.0, W.shape[0])
    lmap = RegularisedLS(W, centres, 0.5)
    alpha, curve = lmap.gcv(lmap.project(y))
    errors = [np.linalg.norm(lmap.solve(y, a) - truth) for a in np.logspace(-6, 3, 64) * lmap.scale]
    assert np.linalg.norm(lmap.solve(y, alpha) - truth) <= 1.3 * min(errors)
    assert 0 < np.argmin(curve) < len(curve) - 1  # a minimum inside the range, not at its edge


def test_the_tv_gradient_is_two_dimensional_and_never_wraps_across_rows():
    Dx, Dy = gradient_operators((3, 4))
    image = np.zeros((3, 4))
    image[1, :] = 5.0  # a row unlike the ones above and below it: no x-difference anywhere
    image[0, 3], image[1, 0] = 1.0, 1.0  # last pixel of row 0 and first of row 1: neighbours only if it wrapped
    gx = (Dx @ image.ravel()).reshape(3, 4)
    gy = (Dy @ image.ravel()).reshape(3, 4)
    assert gx[0, 3] == 0.0 and gx[1, 3] == 0.0  # the far edge: nothing from the next row
    assert gx[1, 0] == 4.0 and gy[0, 1] == 5.0 and gy[2].tolist() == [0.0] * 4


def test_the_tv_gradient_matches_finite_differences():
    grid, W, rng = small_problem(3)
    y, x = rng.normal(size=W.shape[0]), rng.normal(size=grid.nx * grid.ny)
    Dx, Dy = gradient_operators(grid.shape)
    _, grad = tv_objective(x, W, y, 0.7, Dx, Dy)
    step = 1e-6
    for i in rng.choice(len(x), 12, replace=False):
        e = np.zeros_like(x)
        e[i] = step
        numeric = (tv_objective(x + e, W, y, 0.7, Dx, Dy)[0] - tv_objective(x - e, W, y, 0.7, Dx, Dy)[0]) / (2 * step)
        assert np.isclose(grad[i], numeric, rtol=1e-4, atol=1e-6)


def test_tv_recovers_a_blocky_image_from_noisy_pixels():
    rng = np.random.default_rng(4)
    shape = (16, 16)
    truth = np.zeros(shape)
    truth[3:8, 4:12] = 3.0
    truth[10:14, 2:6] = 1.5
    W = sp.identity(truth.size, format="csr")
    y = truth.ravel() + rng.normal(0, 0.5, truth.size)
    x, converged = tv_solve(W, y, shape, mu=0.6)
    assert converged
    assert np.abs(x - truth.ravel()).mean() < 0.6 * np.abs(y - truth.ravel()).mean()
    image = x.reshape(shape)
    assert abs(image[5, 8] - 3.0) < 0.4 and abs(image[12, 3] - 1.5) < 0.4 and image[0, 15] < 0.3


def test_ellipse_weights_cover_the_line_and_the_cache_reuses_revisited_paths():
    grid = Grid((0.0, 0.0, 4.0, 4.0), 0.2)
    path = np.array([[0.1, 2.0, 3.9, 2.0]])
    row = weight_rows(grid, path).toarray().reshape(grid.shape)
    half_width = np.sqrt(3.9 ** 2 - 3.8 ** 2) / 2  # the ellipse's semi-minor axis for lambda = 0.1 m
    ys = grid.centres()[:, 1].reshape(grid.shape)
    assert row[10, 1:-1].min() > 0 and row[np.abs(ys - 2.0) > half_width].sum() == 0
    assert np.isclose(row.max(), 1 / np.sqrt(3.8))
    smooth = weight_rows(grid, path, "exponential").toarray().reshape(grid.shape)
    assert smooth[12].max() > 0 and smooth[12].max() < smooth[10].max()  # fading away from the line
    cache = WeightCache(grid)
    first = cache.matrix(np.vstack([path, [[0.1, 0.1, 3.9, 3.9]]]))
    again = cache.matrix(np.vstack([[[0.1, 0.1, 3.9, 3.9]], path]))
    assert cache.built == 2 and (again[1] != first[0]).nnz == 0


def test_line_weights_fade_with_the_distance_from_the_segment_whatever_its_length():
    grid = Grid((0.0, 0.0, 8.0, 4.0), 0.1)
    centres = grid.centres()
    short, long = np.array([[3.0, 2.0, 5.0, 2.0]]), np.array([[0.05, 2.0, 7.95, 2.0]])
    for path in (short, long):
        row = weight_rows(grid, path, "line").toarray().ravel()
        a, b = path[0, :2], path[0, 2:]
        along = np.clip((centres - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        distance = np.linalg.norm(centres - (a + along[:, None] * (b - a)), axis=1)
        expected = np.where(distance < LINE_CUT * LINE_WIDTH, np.exp(-0.5 * (distance / LINE_WIDTH) ** 2), 0.0)
        np.testing.assert_allclose(row, expected, atol=1e-12)  # past an end, the distance from that end
    on_line = np.argmin(np.linalg.norm(centres - (4.05, 2.05), axis=1))
    assert weight_rows(grid, short, "line")[0, on_line] == weight_rows(grid, long, "line")[0, on_line]


def test_the_sparse_solve_puts_the_attenuation_on_the_few_pixels_that_hold_it():
    rng = np.random.default_rng(2)
    n = 400
    W = sp.csr_matrix(rng.random((120, n)) * (rng.random((120, n)) < 0.3))
    truth = np.zeros(n)
    truth[[37, 211]] = (4.0, 2.5)
    x = sparse_nonnegative(W, W @ truth, share=0.001)
    assert x.min() >= 0
    assert set(np.argsort(x)[-2:]) == {37, 211} and np.abs(x - truth).max() < 0.05
    np.testing.assert_array_equal(x, sparse_nonnegative(W, W @ truth, share=0.001))  # the same image every time


def test_the_sparse_image_is_empty_when_nothing_attenuates():
    grid, W, rng = small_problem()
    assert not sparse_nonnegative(W, np.zeros(W.shape[0])).any()
    assert not sparse_nonnegative(W, -rng.random(W.shape[0])).any()  # gains only: no attenuation to place
    assert not sparse_nonnegative(W, W @ np.ones(W.shape[1]), share=1.0).any()  # at mu_max and above, empty
