"""An SE(2) pose graph and its least-squares solution (Gauss-Newton, sparse, robust loop edges).

Nodes are poses ``(x, y, yaw)``; an edge ``(i, j, z, info)`` says that pose ``j`` seen from pose
``i`` is ``z`` (``i^-1 (+) j``), with information matrix ``info`` (3x3, in ``z``'s frame). The
error of an edge is ``z^-1 (+) (x_i^-1 (+) x_j)`` as ``(R_z^T (R_i^T (t_j - t_i) - t_z),
yaw_j - yaw_i - yaw_z)``; the solution minimises the sum of ``e^T info e`` over the edges (loop
edges through a Cauchy kernel, so a wrong one pulls less the more it disagrees), the first node
held where it is. The normal equations are block-sparse (a chain plus the loop edges): assembled
vectorised over the edges and solved with SciPy's sparse LU.
"""

from __future__ import annotations

import numpy as np

from .geometry import wrap_angle


def edge_errors(x: np.ndarray, i: np.ndarray, j: np.ndarray, z: np.ndarray):
    """Errors ``(E, 3)`` of the edges and their Jacobians ``A = de/dx_i``, ``B = de/dx_j``
    (``(E, 3, 3)`` each) at the poses ``x`` ``(N, 3)``."""
    xi, xj = x[i], x[j]
    ci, si = np.cos(xi[:, 2]), np.sin(xi[:, 2])
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    dx, dy = xj[:, 0] - xi[:, 0], xj[:, 1] - xi[:, 1]
    tx, ty = ci * dx + si * dy, -si * dx + ci * dy  # R_i^T (t_j - t_i)
    ux, uy = tx - z[:, 0], ty - z[:, 1]
    e = np.stack([cz * ux + sz * uy, -sz * ux + cz * uy, wrap_angle(xj[:, 2] - xi[:, 2] - z[:, 2])], axis=1)
    # R_z^T R_i^T = R(-(yaw_i + yaw_z)): rows (c, s), (-s, c) of the summed angle
    c, s = np.cos(xi[:, 2] + z[:, 2]), np.sin(xi[:, 2] + z[:, 2])
    n = len(i)
    a = np.zeros((n, 3, 3))
    b = np.zeros((n, 3, 3))
    b[:, 0, 0], b[:, 0, 1], b[:, 1, 0], b[:, 1, 1], b[:, 2, 2] = c, s, -s, c, 1.0
    a[:, :2, :2] = -b[:, :2, :2]
    # d/dyaw_i of R_z^T R_i^T (t_j - t_i) = R_z^T dR_i^T/dyaw (t_j - t_i) = R_z^T (ty, -tx)
    a[:, 0, 2] = cz * ty - sz * tx
    a[:, 1, 2] = -sz * ty - cz * tx
    a[:, 2, 2] = -1.0
    return e, a, b


def optimize(
    x0: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    z: np.ndarray,
    info: np.ndarray,
    robust: np.ndarray,
    cauchy: float = 1.0,
    iterations: int = 15,
    tol: float = 1e-4,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve the pose graph from ``x0`` ``(N, 3)``; edges ``i, j`` ``(E,)`` int, ``z`` ``(E, 3)``,
    ``info`` ``(E, 3, 3)``, ``robust`` ``(E,)`` bool (Cauchy kernel with scale ``cauchy`` on the
    chi-square). Node 0 stays fixed; the iterations stop once no pose moves by more than ``tol``
    (m, rad). Returns the poses and each edge's chi-square ``e^T info e`` at the solution."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    x = np.array(x0, dtype=np.float64).reshape(-1, 3)
    i = np.asarray(i, dtype=np.int64)
    j = np.asarray(j, dtype=np.int64)
    z = np.asarray(z, dtype=np.float64).reshape(-1, 3)
    info = np.asarray(info, dtype=np.float64).reshape(-1, 3, 3)
    robust = np.asarray(robust, dtype=bool)
    n = x.shape[0]
    if n < 2 or i.size == 0:
        return x, np.zeros(i.size)
    # block (r, c) of every edge's four 3x3 contributions -> coordinates in the 3N x 3N matrix
    rr, cc = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    blocks = [(i, i), (i, j), (j, i), (j, j)]
    rows = np.concatenate([(3 * p[:, None, None] + rr).reshape(len(i), 9) for p, _ in blocks], axis=1).ravel()
    cols = np.concatenate([(3 * q[:, None, None] + cc).reshape(len(i), 9) for _, q in blocks], axis=1).ravel()
    anchor = np.arange(3)
    for _ in range(iterations):
        e, a, b = edge_errors(x, i, j, z)
        chi2 = np.einsum("ek,ekl,el->e", e, info, e)
        w = np.where(robust, 1.0 / (1.0 + chi2 / cauchy**2), 1.0)
        om = info * w[:, None, None]
        at_om = np.einsum("ekl,ekm->elm", a, om)  # A^T Om
        bt_om = np.einsum("ekl,ekm->elm", b, om)
        vals = np.concatenate(
            [
                np.einsum("elm,emn->eln", at_om, a).reshape(-1, 9),
                np.einsum("elm,emn->eln", at_om, b).reshape(-1, 9),
                np.einsum("elm,emn->eln", bt_om, a).reshape(-1, 9),
                np.einsum("elm,emn->eln", bt_om, b).reshape(-1, 9),
            ],
            axis=1,
        ).ravel()
        g = np.zeros(3 * n)
        np.add.at(g, (3 * i[:, None] + np.arange(3)).ravel(), np.einsum("elm,em->el", at_om, e).ravel())
        np.add.at(g, (3 * j[:, None] + np.arange(3)).ravel(), np.einsum("elm,em->el", bt_om, e).ravel())
        h = coo_matrix(
            (
                np.concatenate([vals, np.full(3, 1e12)]),
                (np.concatenate([rows, anchor]), np.concatenate([cols, anchor])),
            ),
            shape=(3 * n, 3 * n),
        ).tocsc()
        dx = spsolve(h, -g).reshape(-1, 3)
        x += dx
        x[:, 2] = wrap_angle(x[:, 2])
        if np.abs(dx).max() < tol:
            break
    e, _, _ = edge_errors(x, i, j, z)
    return x, np.einsum("ek,ekl,el->e", e, info, e)
