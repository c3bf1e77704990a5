"""The two steps of a (extended) Kalman filter, shared by every detector; each detector keeps its paper's symbols
and equation numbers at the call site.

predict: P- = Phi P Phi^T + Q (Phi None: a random walk, P- = P + Q).
update:  S = H P H^T + R, K = P H^T S^-1 (by `solve`, S symmetric), x+ = x + K y for the innovation y the
         caller forms (it may wrap angles), and the Joseph form P+ = (I - K H) P (I - K H)^T + K R K^T, which
         stays symmetric and positive semi-definite under rounding and for any gain (Bucy & Joseph 1968;
         Simon, Optimal State Estimation, 2006, eq. 5.19).

Both are compiled (numba), so a detector's compiled step calls them too. Their products are BLAS's (gemm, gemv)
and the solve LAPACK's (gesv), as numpy's, with each operand in the memory order numpy has it (the gain K is
numpy's transposed solve, column-major, for K y), so they return numpy's bits.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def predict(P, Q, Phi=None):  # pragma: no cover (compiled)
    """The predicted covariance Phi P Phi^T + Q (P + Q for Phi None), symmetrised."""
    if Phi is None:
        P = P + Q
    else:
        P = np.dot(np.dot(Phi, P), Phi.T) + Q
    return 0.5 * (P + P.T)


@njit(cache=True)
def update(x, P, y, H, R):  # pragma: no cover (compiled)
    """Measurement update for the innovation y = z - h(x-); returns (x+, P+, S, K)."""
    R = np.ascontiguousarray(R)                 # a block of a larger matrix (numpy's BLAS call copies it too)
    PHt = np.dot(P, H.T)
    S = np.dot(H, PHt) + R
    K = np.linalg.solve(S, PHt.T).T
    A = np.eye(x.size) - np.dot(K, H)
    P = np.dot(np.dot(A, P), A.T) + np.dot(np.dot(K, R), K.T)
    return x + np.dot(np.asfortranarray(K), y), 0.5 * (P + P.T), S, K
