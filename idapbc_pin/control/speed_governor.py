"""A speed and energy governor that keeps any law from whirling a robot: `SpeedGovernor`.

A law read far from where it was fitted (a release at speed, a push) can pump energy into a whirl
and drive a joint far past its rated speed. The governor sits after every other law and takes
energy out wherever the robot holds clearly more than the upright needs, or a joint runs near its
rated speed; there it never lets the law add energy or speed. In the spirit of the energy pump's E* − E term:

    E_g(x) = ½ v_rᵀ M_rr(q) v_r + U(q),     E* = U(q*),     ΔE = E* − U(q_rest),

the energy of every coordinate but the cyclic actuated ones (a cart, a Furuta arm, a reaction
wheel store energy in their own motion; their speed is governed by their rating instead), and its
rate through the input, exactly, w = ∂Ė_g/∂u = (M⁻¹B)_rᵀ M_rr v_r (m,) (w = v_a when r holds every
coordinate: Ė = uᵀv_a − vᵀDv). With the excess e = (E_g − E*)/ΔE, each joint's speed ratio
ρ_j = |v_j| / v̄_j (v̄ the URDF `<limit velocity>`, passive joints too) and k the joint with the
largest s_v,j, its speed's rate through the input c = v_k (M⁻¹B)_k / max_i |(M⁻¹B)_ki| (m,):

    s_E = clip((e − margin) / ENERGY_BAND, 0, 1),   s_v = max_j clip((ρ_j − SPEED_START) / (1 − SPEED_START), 0, 1),
    where s_v > 0:  u_i ← 0 if u_i c_i > 0;  u_i ← (1 − s_i) u_i − s_i ū_i clip(c_i / W_SCALE, ±1),
                    s_i = max(s_E, s_v) if w_i c_i > 0 (the clauses agree), else s_v;
    elsewhere:      u_i ← 0 if s_E > 0 and u_i w_i > 0;  u_i ← (1 − s_E) u_i − s_E ū_i clip(w_i / W_SCALE, ±1),

ū the effort limit. A joint near its rating comes first: each input's power into ½v_k² is ≤ 0
wherever the speed clause acts (a motor brakes its own joint, or a passive one through the
coupling M⁻¹B), and its power into E_g ≤ 0 wherever only the energy clause acts; clipping to ±ū
keeps each sign. Away from both clauses the input is the law's, unchanged: the learned law near x*
and every swing-up from rest below E* + margin·ΔE and 0.8 of every rating. The margin is
`ENERGY_MARGIN` unless a run's recovery stage raised it to what its kept law's own catches from the
training box reach (`recovery.catch_margin`): a cart that swings its poles up from the box's edge. It is a state
feedback, applied by `Controller` after every outer law and before the rail guard, and the exported
controller applies the same rule (controller.json's "governor").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import System
from ..model.resting import resting_configuration
from .energy_pump import cyclic_coordinates

__all__ = ["ENERGY_BAND", "ENERGY_MARGIN", "SPEED_START", "W_SCALE", "SpeedGovernor"]

#: The energy clause starts where E_g exceeds E* by this share of ΔE = E* − U(q_rest) ...
ENERGY_MARGIN = 0.5
#: ... and brakes at the full effort this share of ΔE further up.
ENERGY_BAND = 0.5
#: The speed clause starts at this share of a joint's rating and brakes at full effort at the rating.
SPEED_START = 0.8
#: Rates |w| (or speeds) below this (rad/s or m/s per unit input) brake proportionally: no chattering at w = 0.
W_SCALE = 0.1


@dataclass(frozen=True, eq=False)
class SpeedGovernor:
    """The governor of a robot (module docstring for the rule).

    Attributes
    ----------
    system : the plant whose M(q) and U(q) give E_g and w.
    energy_rows : (r,) the coordinates whose energy E_g counts (every one but the cyclic actuated ones).
    e_star : E* = U(q*), J. delta_e : ΔE = E* − U(q_rest), J (≤ 0: no energy clause).
    rating : (nq,) each joint's rated speed (rad/s or m/s; URDF `<limit velocity>`), inf where none.
    effort : (m,) ū of each input (finite).
    energy_margin : where the energy clause starts, in ΔE above E* (`ENERGY_MARGIN` by default).
    """

    system: System
    energy_rows: np.ndarray
    e_star: float
    delta_e: float
    rating: np.ndarray
    effort: np.ndarray
    energy_margin: float = ENERGY_MARGIN

    @classmethod
    def of(cls, system: System, energy_margin: float = ENERGY_MARGIN) -> "SpeedGovernor | None":
        """The governor of `system`, or None where an input has no finite effort limit (no braking
        torque is defined) or neither clause could act (no energy gap above rest, no rated joint)."""
        effort = np.asarray(system.effort, dtype=np.float64)
        if not np.isfinite(effort).all():
            return None
        nq = system.nq
        B = np.asarray(system.B, dtype=np.float64)
        driven = np.flatnonzero(np.abs(B).sum(axis=1) > 0)
        cyclic = cyclic_coordinates(system)
        rows = np.array([i for i in range(nq) if not (cyclic[i] and i in driven)], dtype=int)
        q_star = np.asarray(system.x_star, dtype=np.float64)[:nq]
        u_star, u_rest = system.potential(np.stack([q_star, resting_configuration(system)]))
        rating = np.array([j.speed for j in system.joints], dtype=np.float64)
        delta_e = float(u_star - u_rest) if len(rows) else 0.0
        if not (delta_e > 0 or np.isfinite(rating).any()):
            return None
        return cls(system, rows, float(u_star), delta_e, rating, effort, float(energy_margin))

    def energy(self, x, qv: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(E_g (N,) in J, w (N, m) = ∂Ė_g/∂u) at states x (N, n) = (q, p); `qv`: x's (q, v) where
        already split."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        q, v = self.system.split(x) if qv is None else qv
        e_g, M = self._energy(x, q, v)
        return e_g, self._rate(q, v, M)

    def _energy(self, x, q, v) -> tuple[np.ndarray, np.ndarray | None]:
        """(E_g (N,), M(q) (N, nq, nq), or None where E_g is H and w needs no M)."""
        nq = self.system.nq
        if len(self.energy_rows) == nq:  # every coordinate: E_g = H = ½ vᵀp + U
            return 0.5 * np.einsum("ni,ni->n", v, x[:, nq:]) + self.system.potential(q), None
        M, r = self.system.mass_matrix(q), self.energy_rows
        Mv_r = np.einsum("nij,nj->ni", M[:, r][:, :, r], v[:, r])  # M_rr v_r
        return 0.5 * np.einsum("ni,ni->n", v[:, r], Mv_r) + self.system.potential(q), M

    def _rate(self, q, v, M) -> np.ndarray:
        """w (N, m) = (M⁻¹B)_rᵀ M_rr v_r (w = Bᵀv where r holds every coordinate, M None)."""
        B = np.asarray(self.system.B, dtype=np.float64)
        if M is None:
            return v @ B
        r = self.energy_rows
        MinvB = np.linalg.solve(M, np.broadcast_to(B, M.shape[:1] + B.shape))
        return np.einsum("nim,ni->nm", MinvB[:, r], np.einsum("nij,nj->ni", M[:, r][:, :, r], v[:, r]))

    def _levels(self, x):
        """What `shares` needs before the rates: (q, v, M or None, s_E (N,), s_v (N,), k (N,) the
        joint nearest past its start)."""
        q, v = self.system.split(x)
        if self.delta_e > 0:
            e_g, M = self._energy(x, q, v)
            s_e = np.clip(((e_g - self.e_star) / self.delta_e - self.energy_margin) / ENERGY_BAND, 0.0, 1.0)
        else:
            s_e, M = np.zeros(len(x)), None
        with np.errstate(invalid="ignore", divide="ignore"):
            each = np.where(np.isfinite(self.rating), np.clip((np.abs(v) / self.rating - SPEED_START) / (1.0 - SPEED_START), 0.0, 1.0), 0.0)
        k = np.argmax(each, axis=1)
        return q, v, M, s_e, each[np.arange(len(x)), k], k

    def shares(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(s_E (N,), s_v (N,), w (N, m), c (N, m)) at x (N, n): how hard each clause acts, the energy
        rate per input, and the speed clause's direction c = v_k (M⁻¹B)_k / max_i |(M⁻¹B)_ki| for the
        joint k nearest past its start (rad/s or m/s; 0 where the speed clause does not act)."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        return self._shares(*self._levels(x))

    def _shares(self, q, v, M, s_e, s_v, k):
        w = self._rate(q, v, M) if self.delta_e > 0 else np.zeros((len(q), self.system.m))
        c = np.zeros((len(q), self.system.m))
        fast = np.flatnonzero(s_v > 0)
        if len(fast):
            Mf = self.system.mass_matrix(q[fast]) if M is None else M[fast]
            reach = np.linalg.solve(Mf, np.broadcast_to(np.asarray(self.system.B, dtype=np.float64), (len(fast),) + self.system.B.shape))
            reach = reach[np.arange(len(fast)), k[fast]]  # (F, m): ∂v̇_k/∂u
            c[fast] = v[fast, k[fast], None] * reach / np.abs(reach).max(axis=1, keepdims=True)
        return s_e, s_v, w, c

    def apply(self, x, u) -> np.ndarray:
        """The law's inputs u (N, m) at x (N, n), governed (a new array). Where neither clause acts
        anywhere in the batch, the rates are not computed: u comes back as it was."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        u = np.array(u, dtype=np.float64, copy=True).reshape(len(x), -1)
        levels = self._levels(x)
        if not ((levels[3] > 0).any() or (levels[4] > 0).any()):
            return u
        s_e, s_v, w, c = self._shares(*levels)
        speed = (s_v > 0)[:, None]  # a joint near its rating comes first; braked as hard as the energy asks where the two agree
        u = np.where((speed & (u * c > 0)) | (~speed & (s_e[:, None] > 0) & (u * w > 0)), 0.0, u)
        brake = -self.effort * np.clip(np.where(speed, c, w) / W_SCALE, -1.0, 1.0)
        s = np.where(speed, np.where(w * c > 0, np.maximum(s_e, s_v)[:, None], s_v[:, None]), s_e[:, None])
        return (1.0 - s) * u + s * brake

    def to_json(self) -> dict:
        """The governor's settings for controller.json (the exported controller's "governor")."""
        nq = self.system.nq
        return {"energy_rows": self.energy_rows.tolist(), "q_star": np.asarray(self.system.x_star, dtype=np.float64)[:nq].tolist(),
                "q_rest": resting_configuration(self.system).tolist(),
                "rating": [r if np.isfinite(r) else None for r in self.rating.tolist()], "effort": self.effort.tolist(),
                "energy_margin": self.energy_margin, "energy_band": ENERGY_BAND, "speed_start": SPEED_START, "w_scale": W_SCALE}
