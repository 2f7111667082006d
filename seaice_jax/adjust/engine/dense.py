"""The dense backend: the whole whitened Jacobian, its column-scaled form's singular value decomposition.

With J D⁻¹ = W S Vᵀ (D the column norms: units drop out; W = QU the left singular vectors), the damped step is
Δ = −D⁻¹ V S (S² + λ)⁻¹ Wᵀ e, the cofactor of the unknowns (JᵀJ)⁻¹ = D⁻¹ V S⁻² Vᵀ D⁻¹ and the hat matrix's
diagonal ‖W_i‖², all from the factors: the normal matrix is never formed (its condition is the square of
J's), so a problem with cond(J) = 1e8 keeps its digits. Singular values below ``RANK_TOLERANCE`` · s_max are
dropped (a minimum-norm step in an undetermined direction; the engine then names the parameters involved).

Two ways to the same factors (:data:`FACTORIZATIONS`): ``"lapack"`` (the default), QR of J D⁻¹ and SVD of its
triangle (LAPACK: the fastest for one problem, but under ``vmap`` XLA on CPU runs these calls matrix by matrix), and
``"jacobi"``, one-sided Jacobi rotations of the columns of J D⁻¹ until they are orthogonal (Hestenes 1958; Demmel &
Veselić 1992: the small singular values to high relative accuracy) written in elementwise operations, which
vectorize across the lanes of a batch: for a batch of small problems (up to :data:`JACOBI_LIMIT` unknowns, LAPACK
beyond; a sweep's cost and code grow with their square).
"""

import jax
import jax.numpy as jnp

from seaice_jax.adjust.engine.problem import Problem

RANK_TOLERANCE = 1e-12
"""Relative singular value of the column-scaled Jacobian below which a direction counts as undetermined: about
100 × the float64 roundoff of a Jacobian computed to full precision (κ > 1e12 leaves no digit in σ)."""
FACTORIZATIONS = ("lapack", "jacobi")
JACOBI_LIMIT = 8
"""Unknowns up to which ``factorization="jacobi"`` takes the Jacobi rotations (a handful of unknowns: an image's
scan model, a curve fit), beyond which LAPACK's QR and SVD."""
JACOBI_SWEEPS = 30
"""Most sweeps of the Jacobi rotations (LAPACK's ``dgesvj`` cap; a sweep rotates every pair of columns once; the
convergence is quadratic: a few sweeps from an arbitrary matrix, fewer from the previous iteration's rotation)."""
STEP_ORTHOGONALITY = 1e-6
"""|cos| between two rotated columns at which the Jacobi rotations of an iteration's step stop (the statistics
rotate to roundoff): the step is then exact to about this relative accuracy, which leaves Gauss-Newton's
convergence and its fixed point (Jᵀe = 0) as they were, and from the previous iteration's rotation few sweeps
reach it. The test is relative, so a dependent column is still rotated down to roundoff (the rank is kept)."""


def columns(problem: Problem, block):
    """``(m, k + d)`` column of the dense Jacobian for each row's global unknowns then its point coordinates."""
    n = problem.start.shape[0]
    if block.point_index is None:
        return block.global_index
    d = problem.points.shape[1]
    point_columns = n + block.point_index[:, None] * d + jnp.arange(d)[None, :]
    return jnp.concatenate([block.global_index, point_columns], axis=1)


def assemble(problem: Problem, linear: dict):
    """Whitened residual vector ``(M,)`` and Jacobian ``(M, N)``, blocks in order, rows then components."""
    size = problem.unknowns
    residuals, jacobians = [], []
    for name, block in problem.blocks.items():
        lin = linear[name]
        m, c = lin.e.shape
        local = lin.theta if block.point_index is None else jnp.concatenate([lin.theta, lin.point], axis=2)
        where = columns(problem, block)
        rows = jnp.arange(m * c).reshape(m, c)
        matrix = jnp.zeros((m * c, size)).at[rows[:, :, None], where[:, None, :]].add(local)
        residuals.append(lin.e.reshape(-1))
        jacobians.append(matrix)
    return jnp.concatenate(residuals), jnp.concatenate(jacobians)


def column_norms(jacobian):
    """``(N,)`` the Euclidean norms of the Jacobian's columns (the scales D)."""
    return jnp.linalg.norm(jacobian, axis=0)


def uses_jacobi(factorization: str, unknowns: int) -> bool:
    """Whether ``factorization`` (one of :data:`FACTORIZATIONS`) takes the Jacobi rotations for this many
    unknowns."""
    return factorization == "jacobi" and unknowns <= JACOBI_LIMIT


def _dot(a, b):
    """Σ a b over the rows (an elementwise product and a sum: no matrix call under ``vmap``)."""
    return jnp.sum(a * b, axis=0)


def _rotation(a, b, tolerance):
    """cos and sin of the plane rotation that makes columns ``a`` and ``b`` orthogonal (Rutishauser's form: the
    smaller angle, |t| ≤ 1); none (cos 1, sin 0) where they already are (|aᵀb| ≤ tolerance · ‖a‖ ‖b‖)."""
    alpha, beta, gamma = _dot(a, a), _dot(b, b), _dot(a, b)
    needed = jnp.abs(gamma) > tolerance * jnp.sqrt(alpha * beta)
    zeta = (beta - alpha) / jnp.where(needed, 2.0 * gamma, 1.0)
    size = jnp.minimum(jnp.abs(zeta), 1e150)  # ζ² would overflow; beyond, the rotation is the identity to roundoff
    tangent = jnp.where(needed, jnp.where(zeta >= 0, 1.0, -1.0) / (size + jnp.sqrt(1.0 + size**2)), 0.0)
    cosine = 1.0 / jnp.sqrt(1.0 + tangent**2)
    return cosine, cosine * tangent


def _orthogonal(columns, tolerance):
    """Whether every pair of the ``(M, N)`` ``columns`` is orthogonal to ``tolerance`` (the test :func:`_rotation`
    applies)."""
    gram = jnp.sum(columns[:, :, None] * columns[:, None, :], axis=0)
    norms = jnp.diagonal(gram)
    off = ~jnp.eye(columns.shape[1], dtype=bool)
    return jnp.all(jnp.where(off, jnp.abs(gram) <= tolerance * jnp.sqrt(norms[:, None] * norms[None, :]), True))


def jacobi_svd(matrix, rotation=None, orthogonality=None):
    """Thin SVD of ``matrix`` ``(M, N)`` by one-sided (Hestenes) Jacobi rotations: ``(left (M, N), singular (N,),
    vt (N, N))`` with matrix = left · diag(singular) · vt, the singular values in no particular order (a zero one
    has a zero left vector).

    The columns of ``matrix · V`` are rotated pairwise, a sweep through every pair (p, q), p < q, in row order at a
    time, until every pair is orthogonal to ``orthogonality`` (|cos| of their angle; default √M·ε, roundoff) or
    :data:`JACOBI_SWEEPS` sweeps; then the singular values are the columns' norms, the left vectors the columns
    normalized and V the product of the rotations. ``rotation`` ``(N, N)``, an orthogonal V to start from (the
    previous iteration's: a Jacobian that changed little needs a sweep), else the identity. Elementwise operations
    and sums only: under ``vmap`` they vectorize across the lanes. One rotation is the body of a loop over the
    pairs (not the sweep unrolled: XLA compiled the N(N − 1)/2 rotations of the unrolled sweep in seconds).
    """
    rows, size = matrix.shape
    start = matrix if rotation is None else matrix @ rotation
    rotation = jnp.eye(size) if rotation is None else rotation
    tolerance = jnp.sqrt(float(max(rows, 1))) * jnp.finfo(matrix.dtype).eps if orthogonality is None else orthogonality
    pairs = jnp.array([(p, q) for p in range(size - 1) for q in range(p + 1, size)], dtype=int).reshape(-1, 2)

    def rotate(k, state):
        columns, vectors = state
        p, q = pairs[k, 0], pairs[k, 1]
        a, b, u, v = columns[:, p], columns[:, q], vectors[:, p], vectors[:, q]
        cosine, sine = _rotation(a, b, tolerance)
        columns = columns.at[:, p].set(cosine * a - sine * b).at[:, q].set(sine * a + cosine * b)
        vectors = vectors.at[:, p].set(cosine * u - sine * v).at[:, q].set(sine * u + cosine * v)
        return columns, vectors

    def sweep(state):
        columns, vectors, sweeps = state
        return *jax.lax.fori_loop(0, pairs.shape[0], rotate, (columns, vectors)), sweeps + 1

    def running(state):
        return (state[2] < JACOBI_SWEEPS) & ~_orthogonal(state[0], tolerance)

    columns, vectors, _ = jax.lax.while_loop(running, sweep, (start, rotation, jnp.zeros((), int)))
    singular = jnp.sqrt(_dot(columns, columns))
    left = columns / jnp.where(singular > 0, singular, 1.0)[None, :]
    return left, singular, vectors.T


class Factors:
    """Column scales, left singular vectors ``(M, N)`` of J D⁻¹, singular values ``(N,)`` (largest first from
    LAPACK, in no particular order from the Jacobi rotations), right vectors ``vt`` ``(N, N)``.

    Args:
        jacobian: ``(M, N)`` whitened Jacobian.
        scale: ``(N,)`` column scales D (default: the column norms).
        factorization: one of :data:`FACTORIZATIONS`.
        rotation: for the Jacobi rotations, a V ``(N, N)`` to start from (e.g. the previous iteration's ``vt.T``).
        orthogonality: for the Jacobi rotations, where they stop (:func:`jacobi_svd`; default: at roundoff).
    """

    def __init__(self, jacobian, scale=None, factorization: str = "lapack", rotation=None, orthogonality=None):
        scale = column_norms(jacobian) if scale is None else scale
        self.scale = jnp.where(scale > 0, scale, 1.0)
        scaled = jacobian / self.scale[None, :]
        if uses_jacobi(factorization, scaled.shape[1]):
            self.left, self.singular, self.vt = jacobi_svd(scaled, rotation, orthogonality)
        else:
            q, r = jnp.linalg.qr(scaled)
            u, self.singular, self.vt = jnp.linalg.svd(r)
            self.left = q @ u
        self.kept = self.singular > RANK_TOLERANCE * jnp.max(self.singular, initial=0.0)

    def step(self, residuals, damping):
        """Δ ``(N,)`` minimising ‖e + JΔ‖² + λ‖DΔ‖²."""
        s = self.singular
        gain = jnp.where(self.kept, s / jnp.where(self.kept, s**2 + damping, 1.0), 0.0)
        return -(self.vt.T @ (gain * (self.left.T @ residuals))) / self.scale

    def gauss_newton_decrease(self, residuals):
        """‖J Δ_GN‖²: the decrease of the square sum the undamped step predicts (e's part in J's range)."""
        return jnp.sum(jnp.where(self.kept, self.left.T @ residuals, 0.0) ** 2)

    def cofactor(self):
        """(JᵀJ)⁻¹ ``(N, N)`` (a pseudo-inverse over the kept directions)."""
        inverse = jnp.where(self.kept, 1.0 / jnp.where(self.kept, self.singular, 1.0) ** 2, 0.0)
        scaled = (self.vt.T * inverse[None, :]) @ self.vt
        return scaled / jnp.outer(self.scale, self.scale)

    def undetermined(self):
        """``(N,)`` each unknown's largest |component| in a dropped (undetermined) direction of the scaled problem:
        above 0.1, the unknown takes part in a combination the observations cannot determine."""
        return jnp.max(jnp.where(self.kept[:, None], 0.0, jnp.abs(self.vt)), axis=0)

    def hat_diagonal(self):
        """``(M,)`` diagonal of J (JᵀJ)⁻¹ Jᵀ: 1 − redundancy number."""
        return jnp.sum(jnp.where(self.kept[None, :], self.left, 0.0) ** 2, axis=1)

    def residual_correlation(self, redundancy):
        """``(max |ρ|, partner)`` ``(M,)`` each: the largest correlation of an observation's w-statistic with
        another's, and which (flat index), from the residual cofactor I − J (JᵀJ)⁻¹ Jᵀ."""
        left = jnp.where(self.kept[None, :], self.left, 0.0)
        covariance = -(left @ left.T)
        size = redundancy.shape[0]
        root = jnp.sqrt(jnp.maximum(redundancy, 1e-300))
        correlation = jnp.abs(covariance) / jnp.outer(root, root)
        controlled = redundancy > 1e-9
        correlation = jnp.where(controlled[:, None] & controlled[None, :] & ~jnp.eye(size, dtype=bool),
                                correlation, 0.0)
        return jnp.max(correlation, axis=1), jnp.argmax(correlation, axis=1)
