"""Optimal linear assignment of drones to formation slots.

When a new formation is commanded every drone needs a slot. Minimising the sum of *squared* distances (not the sum
of distances) is the choice that keeps drones apart: for an optimal squared-distance assignment, swapping any two
goals never lowers the cost, which is equivalent to ``(a_i - a_j) . (g_i - g_j) >= 0`` for every pair. Two drones
moving synchronously along straight lines from ``a`` to ``g`` (same time profile) are then, at every instant,
at least ``min(start gap, goal gap) / sqrt(2)`` apart (Turpin, Michael and Kumar, "CAPT: Concurrent assignment and
planning of trajectories for multiple robots", IJRR 2014). The formation engine relies on that bound.

The solver is the shortest-augmenting-path form of the Hungarian method (Kuhn-Munkres with Dijkstra-like row
insertion, as in Jonker and Volgenant): O(n^3) in the worst case, with the inner loop over columns vectorised in
numpy, and a greedy start on the reduced costs (column reduction, then every row takes a free zero-cost column) so
that only the rows left over need augmenting. 100 x 100 takes a few milliseconds. There is no scipy dependency on
purpose: the ground station installs with the project's small dependency list.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def min_cost_assignment(cost: npt.ArrayLike) -> tuple[int, ...]:
    """Column assigned to each row so that the total cost is minimal; every row gets a distinct column.

    ``cost`` is an (n, m) matrix of finite numbers with n <= m (more slots than drones is allowed; the unused
    columns are left out). Ties are broken deterministically.
    """
    c = np.array(cost, dtype=np.float64)
    if c.ndim != 2:
        raise ValueError(f"cost must be a 2-D matrix, got shape {c.shape}")
    n_rows, n_cols = c.shape
    if n_rows > n_cols:
        raise ValueError(f"cannot assign {n_rows} rows to {n_cols} columns: need rows <= columns")
    if n_rows == 0:
        return ()
    if not np.all(np.isfinite(c)):
        raise ValueError("cost matrix must be finite")
    # Shifting the whole matrix changes no decision and keeps the dual arithmetic well scaled.
    c = c - c.min()
    return _shortest_augmenting_path(c)


def _shortest_augmenting_path(c: FloatArray) -> tuple[int, ...]:
    n_rows, n_cols = c.shape
    # Dual feasibility: u[i] + v[j] <= c[i, j]. Matched pairs are tight.
    u = c.min(axis=1)
    v = np.zeros(n_cols)
    if n_rows == n_cols:
        v = (c - u[:, None]).min(axis=0)
    col_of_row = np.full(n_rows, -1, dtype=np.int64)
    row_of_col = np.full(n_cols, -1, dtype=np.int64)

    # Greedy start: any free zero-reduced-cost pair may be matched without breaking the invariants.
    reduced = c - u[:, None] - v[None, :]
    tight = reduced <= 0.0
    for i in range(n_rows):
        for j in np.flatnonzero(tight[i]):
            if row_of_col[j] < 0:
                col_of_row[i] = j
                row_of_col[j] = i
                break

    for free_row in np.flatnonzero(col_of_row < 0):
        _augment(int(free_row), c, u, v, col_of_row, row_of_col)
    return tuple(int(j) for j in col_of_row)


def _augment(
    free_row: int,
    c: FloatArray,
    u: FloatArray,
    v: FloatArray,
    col_of_row: npt.NDArray[np.int64],
    row_of_col: npt.NDArray[np.int64],
) -> None:
    """Insert one free row: Dijkstra over columns on reduced costs, then flip the path and update the duals."""
    n_cols = c.shape[1]
    dist = np.full(n_cols, math.inf)  # shortest reduced-cost distance from the free row to each column
    pred_row = np.full(n_cols, -1, dtype=np.int64)  # row we reached each column from
    done = np.zeros(n_cols, dtype=bool)
    done_cols: list[int] = []
    row = free_row
    offset = 0.0  # distance already accumulated when `row` was reached
    while True:
        candidate = offset + c[row] - u[row] - v
        improve = (candidate < dist) & ~done
        dist[improve] = candidate[improve]
        pred_row[improve] = row
        masked = np.where(done, math.inf, dist)
        col = int(np.argmin(masked))
        offset = float(masked[col])
        done[col] = True
        done_cols.append(col)
        if row_of_col[col] < 0:
            break
        row = int(row_of_col[col])

    # Dual update keeps every reduced cost non-negative and makes the new path tight.
    finished = np.array(done_cols[:-1], dtype=np.int64)
    u[free_row] += offset
    if finished.size:
        rows = row_of_col[finished]
        shift = offset - dist[finished]
        u[rows] += shift
        v[finished] -= shift

    col = done_cols[-1]
    while True:
        row = int(pred_row[col])
        previous = int(col_of_row[row])
        col_of_row[row] = col
        row_of_col[col] = row
        if row == free_row:
            break
        col = previous


def squared_distance_cost(starts_m: npt.ArrayLike, goals_m: npt.ArrayLike) -> FloatArray:
    """Matrix of squared Euclidean distances, starts in rows and goals in columns (any dimension)."""
    a = np.asarray(starts_m, dtype=np.float64)
    g = np.asarray(goals_m, dtype=np.float64)
    if a.ndim != 2 or g.ndim != 2 or a.shape[1] != g.shape[1]:
        raise ValueError(f"starts and goals must be (n, d) and (m, d) arrays, got {a.shape} and {g.shape}")
    diff = a[:, None, :] - g[None, :, :]
    return np.asarray(np.einsum("ijk,ijk->ij", diff, diff), dtype=np.float64)


def assign_min_squared_distance(starts_m: npt.ArrayLike, goals_m: npt.ArrayLike) -> tuple[int, ...]:
    """Goal index for each start so that the sum of squared distances is minimal (see the module docstring)."""
    return min_cost_assignment(squared_distance_cost(starts_m, goals_m))


def assignment_cost(cost: npt.ArrayLike, cols: Sequence[int]) -> float:
    """Total cost of an assignment given as the column of each row."""
    c = np.asarray(cost, dtype=np.float64)
    return float(c[np.arange(len(cols)), np.asarray(cols, dtype=np.int64)].sum())
