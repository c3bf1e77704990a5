"""The two steps of a (extended) Kalman filter, shared by every detector; each detector keeps its paper's symbols
and equation numbers at the call site.

predict: P- = Phi P Phi^T + Q (Phi None: a random walk, P- = P + Q).
update:  S = H P H^T + R, K = P H^T S^-1 (by `solve`, S symmetric), x+ = x + K y for the innovation y the
         caller forms (it may wrap angles), and the Joseph form P+ = (I - K H) P (I - K H)^T + K R K^T, which
         stays symmetric and positive semi-definite under rounding and for any gain (Bucy & Joseph 1968;
         Simon, Optimal State Estimation, 2006, eq. 5.19).
"""
from __future__ import annotations

import numpy as np


def predict(P: np.ndarray, Q: np.ndarray, Phi: np.ndarray | None = None) -> np.ndarray:
    """The predicted covariance Phi P Phi^T + Q (P + Q for Phi None), symmetrised."""
    P = P + Q if Phi is None else Phi @ P @ Phi.T + Q
    return 0.5 * (P + P.T)


def update(x: np.ndarray, P: np.ndarray, y: np.ndarray, H: np.ndarray, R: np.ndarray):
    """Measurement update for the innovation y = z - h(x-); returns (x+, P+, S, K)."""
    PHt = P @ H.T
    S = H @ PHt + R
    K = np.linalg.solve(S, PHt.T).T
    A = np.eye(len(x)) - K @ H
    P = A @ P @ A.T + K @ R @ K.T
    return x + K @ y, 0.5 * (P + P.T), S, K
