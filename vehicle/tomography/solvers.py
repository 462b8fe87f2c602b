"""Image from link attenuations: regularised least squares with a spatial prior, and total variation.

Regularised least squares (Wilson and Patwari 2010): x = argmin |W x - y|^2 + alpha x^T C^-1 x, with C the
exponential covariance exp(-distance / delta) of a pixel's attenuation with its neighbours'. By the
push-through identity x = C W^T (W C W^T + alpha I)^-1 y: with the eigendecomposition W C W^T = U S U^T (links x
links, small) the map from measurements to image, for any alpha, is G diag(1 / (S + alpha)) U^T with G = C W^T U,
computed once per set of links; a frame is two matrix-vector products. VRTI's prior (Wilson and Patwari
2011), a Tikhonov penalty on the image's gradient, is the same map with C = Q^-1 (difference_prior_times).
alpha is chosen by generalised cross-validation (Golub, Heath and Wahba 1979), whose terms are cheap in that
basis.

Total variation (Wilson, Patwari and Vasquez): x = argmin 1/2 |W x - y|^2 + mu sum sqrt(dx^2 + dy^2 + eps^2),
with dx, dy forward differences along the image's rows and columns (a true 2-D gradient: nothing wraps from
one row into the next), solved by scipy's L-BFGS-B with the exact gradient, attenuation bounded below by zero.
mu is chosen by the discrepancy principle: the fit's residual matches the noise that GCV estimated.

Sparse (compressive RTI, after Kanso and Rabbat, "Compressed RF tomography for wireless sensor networks", 2009):
x = argmin 1/2 |W x - y|^2 + mu sum x, x >= 0: the lasso with attenuation bounded below by zero, solved by FISTA
(Beck and Teboulle 2009). For people standing still: they are few, each attenuates, and the image is mostly
empty, so the solve puts the attenuation on as few pixels as the links allow. The least-squares image blurs
each person over the prior's correlation length and more where links are few (a team of two measures one
path per pair of spots), and two people 1.5 m apart merged into one blob between them. mu is ``SPARSE_SHARE``
of mu_max = max(W^T y), above which the image is empty (the lasso's usual scale: glmnet's path starts there).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import minimize
from scipy.sparse.linalg import splu

ALPHAS = np.logspace(-6, 3, 64)  # candidate alpha, relative to the largest eigenvalue of W C W^T
TV_EPS = 0.01  # dB per pixel: smooths the kink of |gradient| at zero, far below any edge we image
SPARSE_SHARE = 0.05  # of mu_max: two targets 1.5 m apart imaged apart in 19 of 20 simulated missions at 0.05, 18
# at 0.01 and 17 at 0.2 (the choice is not delicate); 0 would fit the noise, 1 leaves the image empty
SPARSE_ITERATIONS = 3000
DENSE_ELEMENTS = 2_000_000  # paths x pixels up to which the solve works on a dense copy (16 MB)
SPARSE_TOL = 1e-7  # the largest change of a pixel per iteration, relative to the largest pixel


def prior_times(centres: np.ndarray, W: sp.csr_matrix, delta: float) -> np.ndarray:
    """C W^T (pixels x links) without holding C: a block of C's rows at a time."""
    out = np.empty((len(centres), W.shape[0]))
    for start in range(0, len(centres), 1024):
        block = centres[start:start + 1024]
        distance = np.sqrt(((block[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2))
        out[start:start + 1024] = (W @ np.exp(-distance / delta).T).T
    return out


def difference_prior_times(shape: tuple[int, int], W: sp.csr_matrix, reach: float) -> np.ndarray:
    """Q^-1 W^T (pixels x links) for the Tikhonov prior Q = Dx'Dx + Dy'Dy + I / reach^2 (``reach`` in pixels),
    by one sparse factorisation. The gradient term is VRTI's (Wilson and Patwari 2011); alone its correlations
    reach across the whole image (the 2-D Laplacian's are logarithmic), so the ridge sets how far a pixel's
    value carries: x'Qx is the precision of a Gaussian Markov field whose correlation length is ``reach``
    (Whittle's, the SPDE (1/reach^2 - Laplacian) x = noise), the same size as the exponential prior's."""
    Dx, Dy = gradient_operators(shape)
    n = shape[0] * shape[1]
    Q = (Dx.T @ Dx + Dy.T @ Dy + sp.identity(n) / reach ** 2).tocsc()
    return splu(Q).solve(np.asarray(W.T.todense()))


class RegularisedLS:
    """The precomputed linear map of one set of links (rows of W): x = C W^T (W C W^T + alpha I)^-1 y for the
    prior covariance C, given as the exponential covariance of pixels ``delta`` apart, or as ``B`` = C W^T."""

    def __init__(self, W: sp.csr_matrix, centres: np.ndarray, delta: float, B: np.ndarray | None = None):
        B = prior_times(centres, W, delta) if B is None else B
        K = np.asarray(W @ B)
        S, U = np.linalg.eigh((K + K.T) / 2)
        self.S = np.clip(S, 0.0, None)
        self.U = U
        self.G = B @ U
        self.scale = float(self.S.max()) if len(S) and self.S.max() > 0 else 1.0

    def project(self, y: np.ndarray) -> np.ndarray:
        """U^T y (one frame as a vector, or frames as columns)."""
        return self.U.T @ y

    def gcv(self, z: np.ndarray) -> tuple[float, np.ndarray]:
        """Generalised cross-validation over ALPHAS for projected frames z (links x frames, pooled): the best
        alpha and the GCV curve. GCV(alpha) = m |(I - A) y|^2 / trace(I - A)^2, A = K (K + alpha I)^-1."""
        z2 = np.atleast_2d(z.T).T ** 2
        alphas = ALPHAS * self.scale
        shrink = alphas[None, :] / (self.S[:, None] + alphas[None, :])  # the eigenvalues of I - A
        residual = (shrink ** 2).T @ z2.sum(axis=1)
        trace = shrink.sum(axis=0)
        curve = len(self.S) * residual / np.maximum(trace, 1e-12) ** 2
        return float(alphas[int(np.argmin(curve))]), curve

    def solve(self, y: np.ndarray, alpha: float) -> np.ndarray:
        return self.G @ (self.project(y) / (self.S + alpha))

    def fitted(self, y: np.ndarray, alpha: float) -> np.ndarray:
        """W x: what the image predicts for each link."""
        return self.U @ (self.S / (self.S + alpha) * self.project(y))

    def loo_residuals(self, y: np.ndarray, alpha: float) -> np.ndarray:
        """Leave-one-out residuals (y_i minus what the other links predict for link i), exactly:
        r_i / (1 - A_ii)."""
        hat = (self.U ** 2) @ (self.S / (self.S + alpha))
        return (y - self.fitted(y, alpha)) / np.maximum(1.0 - hat, 1e-9)

    def noise_variance(self, y: np.ndarray, alpha: float) -> float:
        """Wahba's estimate of the measurement noise variance at alpha: |(I - A) y|^2 / trace(I - A)."""
        shrink = alpha / (self.S + alpha)
        return float(np.sum((shrink * self.project(y)) ** 2) / max(shrink.sum(), 1e-12))


def gradient_operators(shape: tuple[int, int]) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Forward differences along x (within each row) and along y (between rows) of an image of ``shape``
    (ny, nx) flattened row by row; zero at the far edge (Neumann), never wrapping into the next row."""
    ny, nx = shape

    def forward(n: int) -> sp.csr_matrix:
        d = sp.diags([-np.ones(n), np.ones(n - 1)], [0, 1], shape=(n, n), format="lil")
        d[n - 1, n - 1] = 0.0
        return d.tocsr()

    return (sp.kron(sp.identity(ny), forward(nx), format="csr"),
            sp.kron(forward(ny), sp.identity(nx), format="csr"))


def tv_objective(x: np.ndarray, W, y: np.ndarray, mu: float, Dx, Dy, eps: float = TV_EPS):
    """1/2 |W x - y|^2 + mu sum sqrt(dx^2 + dy^2 + eps^2), and its exact gradient."""
    r = W @ x - y
    gx, gy = Dx @ x, Dy @ x
    norm = np.sqrt(gx ** 2 + gy ** 2 + eps ** 2)
    value = 0.5 * float(r @ r) + mu * float(norm.sum())
    grad = W.T @ r + mu * (Dx.T @ (gx / norm) + Dy.T @ (gy / norm))
    return value, np.asarray(grad).ravel()


def tv_solve(W, y: np.ndarray, shape: tuple[int, int], mu: float, x0: np.ndarray | None = None,
             eps: float = TV_EPS, nonnegative: bool = True, tol: float = 1e-9) -> tuple[np.ndarray, bool]:
    """The TV image and whether L-BFGS-B converged (its gradient and objective tests)."""
    Dx, Dy = gradient_operators(shape)
    n = shape[0] * shape[1]
    start = np.zeros(n) if x0 is None else np.clip(x0, 0.0, None) if nonnegative else x0
    result = minimize(tv_objective, start, args=(W, y, mu, Dx, Dy, eps), jac=True, method="L-BFGS-B",
                      bounds=[(0.0, None)] * n if nonnegative else None,
                      options={"maxiter": 2000, "ftol": tol, "gtol": 1e-7})
    return result.x, bool(result.success)


def tv_discrepancy(W, y: np.ndarray, shape: tuple[int, int], target: float, x0: np.ndarray | None = None,
                   steps: int = 10) -> tuple[np.ndarray, float, bool]:
    """TV with mu chosen by the discrepancy principle: the largest mu whose misfit |W x - y|^2 stays within
    ``target`` (the noise GCV estimated), by bisection on log mu; when even the smallest mu tried misfits more
    (the bound at zero keeps TV from fitting negative noise), that smallest one. Returns the image, mu and
    whether its solve converged."""
    lo, hi = -4.0, 3.0  # log10 mu, relative to |W^T y|_inf, which makes x = 0 optimal at hi = 0
    scale = float(np.abs(W.T @ y).max()) or 1.0
    within = closest = None
    for _ in range(steps):
        mid = (lo + hi) / 2
        x, ok = tv_solve(W, y, shape, scale * 10 ** mid, x0=x0)
        if float(np.sum((W @ x - y) ** 2)) > target:
            hi, closest = mid, (x, scale * 10 ** mid, ok)
        else:
            lo, within, x0 = mid, (x, scale * 10 ** mid, ok), x
    return within or closest


def sparse_nonnegative(W, y: np.ndarray, share: float = SPARSE_SHARE) -> np.ndarray:
    """The sparse, non-negative image (see the module's docstring) by FISTA, from an empty image."""
    W = sp.csr_matrix(W)
    n = W.shape[1]
    WT = W.T.tocsr()
    if W.shape[0] * n <= DENSE_ELEMENTS:  # a few paths: dense products are several times faster
        W, WT = W.toarray(), WT.toarray()
    mu_max = float((WT @ y).max()) if len(y) else 0.0
    if mu_max <= 0.0:
        return np.zeros(n)  # nothing attenuates: the empty image is optimal
    gram = W @ WT  # paths x paths: its largest eigenvalue exactly, so the image is the same every time
    lipschitz = float(np.linalg.eigvalsh(gram.toarray() if sp.issparse(gram) else gram)[-1])
    mu, step = share * mu_max, 1.0 / lipschitz
    x = z = np.zeros(n)
    t = 1.0
    for _ in range(SPARSE_ITERATIONS):
        following = np.maximum(z - step * (WT @ (W @ z - y) + mu), 0.0)
        change = float(np.abs(following - x).max())
        t_next = (1.0 + np.sqrt(1.0 + 4.0 * t * t)) / 2.0
        z = following + (t - 1.0) / t_next * (following - x)
        x, t = following, t_next
        if change <= SPARSE_TOL * max(float(x.max()), 1e-12):
            break
    return x
