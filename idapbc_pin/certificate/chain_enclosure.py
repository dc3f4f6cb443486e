"""Interval enclosures of a URDF plant's open loop over boxes of states: f(x) = (v, −∂H/∂q − Dv)
for a tree of revolute, continuous and prismatic joints (`model.chain.Chain`).

Over a box of (q, p) the kinematics run on intervals, joint by joint from the base: each joint's
frame (R_k, p_k), its world axis z_k, each body's centre c_k; then the Jacobian columns (revolute:
z_j and z_j × (c_i − p_j); prismatic: 0 and z_j), M(q) = Σ m J_cᵀJ_c + J_ωᵀ I J_ω (the angular
columns in the body's own frame) plus the armature, and U(q) = −Σ m gᵀc. The angles enter as jets
(`jet.Jet`), so the same pass encloses ∂M/∂q_k and ∂U/∂q_k; then v = M⁻¹p by elimination (M is
positive definite: each pivot is met with (0, ∞)) and

    ṗ_k = ½ vᵀ (∂M/∂q_k) v − ∂U/∂q_k − D_k v_k.

Given a jet of the boxes (`Jet.variables`), the result is a jet: f and ∂f/∂x over the boxes. Constants
of the URDF enter as they are stored (float64); a product of two of them is rounded outward, and an
exact 0 or ±1 (an axis, an identity placement) skips its product.
"""

from __future__ import annotations

import numpy as np

from .interval import Interval
from .jet import Jet, stack

__all__ = ["ChainEnclosure"]


def _const(a) -> bool:
    return isinstance(a, float)


def _mul(a, b):
    if _const(a) and _const(b):
        if a in (0.0, 1.0, -1.0) or b in (0.0, 1.0, -1.0):
            return a * b
        return Interval.point(a) * b
    if _const(b):
        a, b = b, a
    if _const(a):
        if a == 0.0:
            return 0.0
        if a == 1.0:
            return b
        if a == -1.0:
            return -b
        return b * a
    return a * b


def _add(a, b):
    if _const(a) and a == 0.0:
        return b
    if _const(b) and b == 0.0:
        return a
    if _const(a) and _const(b):
        return Interval.point(a) + b
    return b + a if _const(a) else a + b


def _neg(a):
    return -a


def _sum(terms):
    out = 0.0
    for t in terms:
        out = _add(out, t)
    return out


def _matmul(A, B):
    """3×3 (lists) A @ B."""
    return [[_sum(_mul(A[i][k], B[k][j]) for k in range(3)) for j in range(3)] for i in range(3)]


def _matvec(A, b):
    return [_sum(_mul(A[i][k], b[k]) for k in range(3)) for i in range(3)]


def _tvec(A, b):
    """Aᵀ b."""
    return [_sum(_mul(A[k][i], b[k]) for k in range(3)) for i in range(3)]


def _cross(a, b):
    """a × b (3-lists); a zero factor skips its product (`_mul`)."""
    return [_add(_mul(a[1], b[2]), _neg(_mul(a[2], b[1]))),
            _add(_mul(a[2], b[0]), _neg(_mul(a[0], b[2]))),
            _add(_mul(a[0], b[1]), _neg(_mul(a[1], b[0])))]


def _floats(a) -> list:
    return [float(x) for x in a]


def _rotation(axis: np.ndarray, c, s):
    """The rotation by the angle with cosine c and sine s about the unit `axis` (3×3 lists)."""
    nz = np.flatnonzero(axis)
    if len(nz) == 1 and abs(axis[nz[0]]) == 1.0:
        i, sign = int(nz[0]), float(axis[nz[0]])
        j, k = (i + 1) % 3, (i + 2) % 3
        R = [[0.0] * 3 for _ in range(3)]
        R[i][i] = 1.0
        R[j][j], R[k][k] = c, c
        ss = s if sign > 0 else -s
        R[k][j], R[j][k] = ss, -ss
        return R
    a = _floats(axis)
    K = [[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]]
    one_c = _add(1.0, _neg(c))
    return [[_add(_add(c if i == j else 0.0, _mul(K[i][j], s)), _mul(a[i] * a[j] if a[i] * a[j] in (0.0, 1.0) else Interval.point(a[i]) * a[j], one_c))
             for j in range(3)] for i in range(3)]


_EYE = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


class ChainEnclosure:
    """f over boxes of states for a plant with a `Chain` (module docstring)."""

    def __init__(self, chain, damping: np.ndarray):
        self.chain = chain
        self.damping = np.asarray(damping, np.float64)

    def _world(self, q):
        """Each joint's world frame (R_k, p_k) and each body's centre c_k (lists of 3 / 3×3)."""
        ch = self.chain
        frames, points, centres = [], [], []
        for k in range(ch.size):
            par = ch.parent[k]
            R_par = _EYE if par < 0 else frames[par]
            p_par = [0.0, 0.0, 0.0] if par < 0 else points[par]
            A = _matmul(R_par, [_floats(r) for r in ch.rotation[k]])
            p = [_add(p_par[i], t) for i, t in enumerate(_matvec(R_par, _floats(ch.translation[k])))]
            if ch.prismatic[k]:
                R = A
                p = [_add(p[i], _mul(z, q[:, k])) for i, z in enumerate(_matvec(A, _floats(ch.axis[k])))]
            else:
                R = _matmul(A, _rotation(ch.axis[k], q[:, k].cos(), q[:, k].sin()))
            frames.append(R)
            points.append(p)
            centres.append([_add(p[d], t) for d, t in enumerate(_matvec(R, _floats(ch.lever[k])))])
        return centres

    def _columns(self, q, i):
        """Body i's Jacobian columns in its own frame: {j: (linear, angular or None)} for j moving it.
        Frame j maps into frame i through the relative transforms along the chain, so the angles of
        the joints below j never enter (M does not depend on them)."""
        ch = self.chain
        lever = _floats(ch.lever[i])
        R, o = _EYE, [0.0, 0.0, 0.0]  # frame k -> frame i, starting at k = i
        cols, k = {}, i
        while k >= 0:
            a = _floats(ch.axis[k])
            w = _matvec(R, a)
            if ch.prismatic[k]:
                cols[k] = (w, None)
            else:
                cols[k] = (_cross(w, [_add(lever[d], _neg(o[d])) for d in range(3)]), w)
            # frame parent -> frame k: x_k = Aᵀ(x_par − t0) − [prismatic] a q
            A = [_floats(r) for r in ch.rotation[k]]
            if not ch.prismatic[k]:
                A = _matmul(A, _rotation(ch.axis[k], q[:, k].cos(), q[:, k].sin()))
            At = [[A[c][r] for c in range(3)] for r in range(3)]
            shift = [_neg(e) for e in _matvec(At, _floats(ch.translation[k]))]
            if ch.prismatic[k]:
                shift = [_add(shift[d], _neg(_mul(a[d], q[:, k]))) for d in range(3)]
            o = [_add(o[d], e) for d, e in enumerate(_matvec(R, shift))]
            R = _matmul(R, At)
            k = ch.parent[k]
        return cols

    def energies(self, q):
        """(M (K×K lists), U) over q (N, K): jets in q where ``q`` is a `Jet` of the angles (their
        gradients are ∂M/∂q_k and ∂U/∂q_k), else intervals."""
        ch = self.chain
        K = ch.size
        centres = self._world(q)
        M = [[float(ch.armature[a]) if a == b else 0.0 for b in range(K)] for a in range(K)]
        U = 0.0
        for i in range(K):
            m = float(ch.mass[i])
            U = _add(U, _neg(_sum(_mul(_mul(m, float(ch.gravity[d])), centres[i][d]) for d in range(3))))
            cols = self._columns(q, i)
            I = [_floats(r) for r in ch.inertia[i]]
            for a_ in cols:
                for b_ in cols:
                    if b_ < a_:
                        continue
                    (la, wa), (lb, wb) = cols[a_], cols[b_]
                    term = _mul(m, _sum(_mul(la[d], lb[d]) for d in range(3)))
                    if wa is not None and wb is not None:
                        term = _add(term, _sum(_mul(wa[d], _sum(_mul(I[d][e], wb[e]) for e in range(3))) for d in range(3)))
                    M[a_][b_] = _add(M[a_][b_], term)
        for a_ in range(K):
            for b_ in range(a_):
                M[a_][b_] = M[b_][a_]
        return M, U

    def __call__(self, X):
        """f (N, n) over the boxes X (N, n): an `Interval`, or a `Jet` of them (then f's jet)."""
        K = self.chain.size
        qv = Jet.variables(X[:, :K])
        M, U = self.energies(qv)
        Mx = [[_part(e, None) for e in row] for row in M]
        v = _solve(Mx, [X[:, K + j] for j in range(K)])
        pdot = []
        for k in range(K):
            quad = _sum(_mul(_mul(v[a], _part(M[a][b], k)), v[b]) for a in range(K) for b in range(K))
            term = _add(_mul(0.5, quad), _neg(_part(U, k)))
            if self.damping[k]:
                term = _add(term, _neg(_mul(float(self.damping[k]), v[k])))
            pdot.append(term)
        like = X[:, 0]
        return stack([_full(e, like) for e in v + pdot], axis=1)

    def mass_and_potential(self, q: Interval):
        """(M (N, K, K), U (N,)) over boxes of postures q (N, K) (`Interval`s)."""
        M, U = self.energies(q)
        like = q[:, 0]
        rows = [stack([_full(e, like) for e in row], axis=1) for row in M]
        return stack(rows, axis=1), _full(U, like)


def _part(e, k):
    """The value (k None) or ∂/∂q_k of a quantity computed over angle jets (a constant: itself / 0)."""
    if isinstance(e, Jet) and k is None:
        return e.val
    if isinstance(e, Jet):
        return e.grad[:, k]
    return e if k is None else 0.0


def _full(e, like):
    """e as `like`'s type and shape (constants broadcast)."""
    if isinstance(e, (Jet, Interval)) and e.shape == like.shape:
        return e
    return like * 0.0 + e


def _mid(e):
    while isinstance(e, Jet):
        e = e.val
    return e if _const(e) else e.mid


def _solve(M, p):
    """v with M v = p: elimination without pivoting on C M v = C p, C = mid(M)⁻¹ per box (a point
    matrix, so C M is near I over a small box); M positive definite, so C M is non-singular."""
    K = len(p)
    N = p[0].shape[0]
    mid = np.empty((N, K, K))
    for a in range(K):
        for b in range(K):
            mid[:, a, b] = _mid(M[a][b])
    C = np.linalg.inv(mid)
    pc = lambda a, b: Interval.point(C[:, a, b])  # noqa: E731
    A = [[_sum(_mul(pc(r, k), M[k][c]) for k in range(K)) for c in range(K)] for r in range(K)]
    b = [_sum(_mul(pc(r, k), p[k]) for k in range(K)) for r in range(K)]
    for i in range(K):
        piv = A[i][i]
        inv = Interval.point(piv).reciprocal() if _const(piv) else _nonzero(piv).reciprocal()
        for r in range(i + 1, K):
            f = _mul(A[r][i], inv)
            for c in range(i + 1, K):
                A[r][c] = _add(A[r][c], _neg(_mul(f, A[i][c])))
            b[r] = _add(b[r], _neg(_mul(f, b[i])))
        A[i] = [_mul(e, inv) for e in A[i]]
        b[i] = _mul(b[i], inv)
    v = [None] * K
    for i in range(K - 1, -1, -1):
        v[i] = _add(b[i], _neg(_sum(_mul(A[i][c], v[c]) for c in range(i + 1, K))))
    return v


def _nonzero(piv):
    """A pivot whose enclosure may reach 0 (a box too wide): met with [1e-300, ∞) where it is
    positive at the centre — the enclosure then holds a huge 1/pivot and the box stays undecided —
    and refused as NaN otherwise."""
    lo = piv.lo if not isinstance(piv, Jet) else _flat_lo(piv)
    if np.all(lo > 0):
        return piv
    return piv.meet(1e-300)


def _flat_lo(e):
    while isinstance(e, Jet):
        e = e.val
    return e.lo
