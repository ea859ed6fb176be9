"""The LoG-GP's tree routing (compiled): which leaves an input reaches, with which weight.

A split node j of the tree holds the split dimension ``dim``, the overlap ``[lo, hi]`` and its
children ``left``, ``right`` (a leaf: ``dim = −1``).  An input x goes left with probability
``p = clip((hi − x_j)/(hi − lo), 0, 1)`` (the linear ramp of the LoG-GP, Lederer et al., ICML
2021); the prediction merges every leaf reached with ω > 0, ω the product of the branch
probabilities on its path.  :func:`route` returns, for every row of a batch, each leaf reached
and ω, and optionally ∂ω/∂x (for the merged mean's Jacobian, eq:moejac):
∂(ω p)/∂x = p ∂ω/∂x + ω ∂p/∂x with ∂p/∂x_j = −1/(hi − lo).

:class:`Tree` is the arrays form of the tree whose fields :func:`route` takes.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from sea_daemon.core.jit import njit, warmer


class Tree(NamedTuple):
    """The tree as arrays: ``links`` (3, nodes) int64 rows dim, left, right; ``span``
    (2, nodes) float rows lo, hi."""

    links: np.ndarray
    span: np.ndarray

    @classmethod
    def of(cls, dim, lo, hi, left, right) -> "Tree":
        return cls(np.array([dim, left, right], dtype=np.int64), np.array([lo, hi], dtype=float))


class TreeMirror:
    """The arrays form (:attr:`tree`) of a tree held as parallel lists ``dim, left, right, lo,
    hi`` (:class:`~sea_daemon.core.gp.loggp.LoGGP`), with room to grow: columns beyond the node
    count are never reached (routing starts at the root and follows the links).  Built from the
    lists once; a split writes its nodes (:meth:`written`), so no step copies the whole tree
    (at 10⁶ points, 3·10⁴ nodes: ~8 ms)."""

    __slots__ = ("lists", "n", "tree")

    def __init__(self, dim: list, left: list, right: list, lo: list, hi: list):
        n = len(dim)
        links = np.full((3, max(64, 2 * n)), -1, dtype=np.int64)
        span = np.zeros((2, links.shape[1]))
        links[:, :n] = [dim, left, right]
        span[:, :n] = [lo, hi]
        self.lists = (dim, left, right, lo, hi)
        self.n = n
        self.tree = Tree(links, span)

    def mirrors(self, dim: list) -> bool:
        """Whether this is the mirror of the lists ``dim`` belongs to, at their length."""
        return self.lists[0] is dim and self.n == len(dim)

    def written(self, nodes, added: int) -> bool:
        """Write ``nodes`` of the lists (a split node and its ``added`` new children) into the
        arrays, doubling them when full.  False (nothing written) if the lists grew by other
        than ``added`` since the last write: the mirror missed a change."""
        dim, left, right, lo, hi = self.lists
        n = len(dim)
        if self.n + added != n:
            return False
        t = self.tree
        if n > t.links.shape[1]:
            m = t.links.shape[1]
            links = np.full((3, 2 * n), -1, dtype=np.int64)
            span = np.zeros((2, 2 * n))
            links[:, :m] = t.links
            span[:, :m] = t.span
            t = self.tree = Tree(links, span)
        for i in nodes:
            t.links[0, i], t.links[1, i], t.links[2, i] = dim[i], left[i], right[i]
            t.span[0, i], t.span[1, i] = lo[i], hi[i]
        self.n = n
        return True


@njit
def route(Z, links, span, grad):
    """Leaves reached by every row of ``Z`` (m, ρ) in the tree ``links``, ``span`` (the fields
    of a :class:`Tree`): ``(row, node, ω, ∂ω/∂x)``, arrays of equal length (∂ω/∂x of shape
    (·, ρ), zeros without ``grad``), rows in order, each row's leaves in depth-first order,
    left first.  Compiled; callable from other compiled code.

    Every walk is bounded by the node count: a row that visits more nodes than the tree has,
    or a link outside it, raises ValueError (a tree with a loop or a stray link; a loaded tree
    is checked before use, :func:`~sea_daemon.core.gp.loggp_state.check_tree`), so no tree
    can keep it running."""
    dim, left, right = links[0], links[1], links[2]
    lo, hi = span[0], span[1]
    n_nodes = dim.shape[0]
    rho = Z.shape[1]
    cap = 2 * Z.shape[0] + 8
    idx = np.empty(cap, dtype=np.int64)
    nodes = np.empty(cap, dtype=np.int64)
    ws = np.empty(cap)
    dws = np.zeros((cap, rho))
    st_node = np.empty(64, dtype=np.int64)
    st_w = np.empty(64)
    st_dw = np.zeros((64, rho))
    k = 0
    for i in range(Z.shape[0]):
        node = 0
        steps = 0
        while True:                                  # fast path: no overlap on the way
            if node < 0 or node >= n_nodes or steps > n_nodes:
                raise ValueError("LoG-GP tree: a walk leaves the tree or outlasts its node count")
            steps += 1
            j = dim[node]
            if j < 0:
                break
            xj = Z[i, j]
            if xj <= lo[node]:
                node = left[node]
            elif xj >= hi[node]:
                node = right[node]
            else:
                break
        st_node[0] = node
        st_w[0] = 1.0
        st_dw[0, :] = 0.0
        top = 1
        while top > 0:
            top -= 1
            node = st_node[top]
            if node < 0 or node >= n_nodes or steps > 2 * n_nodes:
                raise ValueError("LoG-GP tree: a walk leaves the tree or outlasts its node count")
            steps += 1
            w = st_w[top]
            j = dim[node]
            if j < 0:
                if k == cap:
                    cap *= 2
                    idx2 = np.empty(cap, dtype=np.int64)
                    nodes2 = np.empty(cap, dtype=np.int64)
                    ws2 = np.empty(cap)
                    dws2 = np.zeros((cap, rho))
                    idx2[:k] = idx[:k]
                    nodes2[:k] = nodes[:k]
                    ws2[:k] = ws[:k]
                    dws2[:k] = dws[:k]
                    idx, nodes, ws, dws = idx2, nodes2, ws2, dws2
                idx[k] = i
                nodes[k] = node
                ws[k] = w
                if grad:
                    dws[k, :] = st_dw[top]
                k += 1
                continue
            if top + 2 > st_node.shape[0]:
                st_node2 = np.empty(2 * st_node.shape[0], dtype=np.int64)
                st_w2 = np.empty(2 * st_node.shape[0])
                st_dw2 = np.zeros((2 * st_node.shape[0], rho))
                st_node2[:top] = st_node[:top]
                st_w2[:top] = st_w[:top]
                st_dw2[:top] = st_dw[:top]
                st_node, st_w, st_dw = st_node2, st_w2, st_dw2
            xj = Z[i, j]
            if xj <= lo[node]:
                st_node[top] = left[node]
                st_w[top] = w
                top += 1
            elif xj >= hi[node]:
                st_node[top] = right[node]
                st_w[top] = w
                top += 1
            else:
                io = 1.0 / (hi[node] - lo[node])
                p = (hi[node] - xj) * io
                q = 1.0 - p
                # right pushed first, left popped first
                st_node[top] = right[node]
                st_w[top] = w * q
                st_node[top + 1] = left[node]
                st_w[top + 1] = w * p
                if grad:
                    # ∂(ω p)/∂x = p ∂ω/∂x + ω ∂p/∂x, ∂p/∂x_j = −1/(hi − lo); the right branch 1 − p
                    for l in range(rho):
                        dw = st_dw[top, l]
                        st_dw[top, l] = dw * q
                        st_dw[top + 1, l] = dw * p
                    st_dw[top + 1, j] -= w * io
                    st_dw[top, j] += w * io
                top += 2
    return idx[:k].copy(), nodes[:k].copy(), ws[:k].copy(), dws[:k].copy()


@warmer
def _warm() -> None:
    """:func:`route` with the argument types :class:`~sea_daemon.core.gp.loggp.LoGGP` uses."""
    tree = Tree.of([0, -1, -1], [-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [1, -1, -1], [2, -1, -1])
    for grad in (False, True):
        route(np.zeros((2, 1)), tree.links, tree.span, grad)
