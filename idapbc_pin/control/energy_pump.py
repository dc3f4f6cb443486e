"""`EnergyPumpLaw`: the classical energy-pumping swing-up that hands over to LQR near x* (DESIGN §4).

The swing-up reference, as `LQRController` is the reference on the box: built in, the same for
every robot, its gains read off the robot's own numbers (effort limits, energies, inertias), never
tuned per robot. Far from x* the actuated joints pump an energy E toward its value at the target,

    u = sat(k (E* − E) ỹ − K_p (q_a − q*_a) − K_d v_a),     E* = H(x*) = U(q*),

with ỹ the pumping direction y with its magnitude floored at `kick` (sign(0) = +1: a start exactly
at rest gets a push instead of no input). The model tells two kinds of actuated joint apart (does
the potential depend on the joint?), and they give the two classical forms:

* a joint the potential depends on (a pendubot's shoulder, an acrobot's elbow) pumps the
  Hamiltonian, E = H, through its own velocity, y = v_a, H's passive output: Ė = uᵀv_a without
  damping, of the sign of E* − E, so in continuous time E climbs to E* and never moves away from it
  (Spong; Fantoni & Lozano); held over a step, the saturated law keeps E in a band about E*;
* a cyclic joint c, one the potential ignores (a cart, a Furuta arm, a reaction wheel), would only
  store energy in its own motion; the energy pumped is that of the other coordinates r,
  E = ½ v_rᵀ M_rr v_r + U(q), which c changes through its acceleration, Ė = −v_rᵀ M_rc v̇_c + ...,
  so y = −M_cr v_r / ‖M_cr(q*)‖ (a velocity of r, rad/s). For a cart-pole this is Åström &
  Furuta, "Swinging up a pendulum by energy control", Automatica 36 (2000): a cart force ∝ ±(E* − E) θ̇ cos θ
  (the sign set by the model's axes). The cyclic joint's own motion is damped (K_d: a wheel or an arm kept
  from spinning up) and a prismatic one is pulled toward its target (K_p: a cart kept on its rail),
  critically damped at `CART_FREQUENCY`.

Once every posture angle (the angles that are not cyclic) is within `catch` of x*'s, wrapped,
saturated LQR takes over. The law is a function of x alone (no switching state), and pickles.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import IdapbcError
from ..model.angles import wrap_angles
from ..model.resting import resting_configuration
from .baseline import LQRController

__all__ = ["CART_FREQUENCY", "DEFAULT_CATCH", "DEFAULT_KICK", "SATURATED_SHARE", "EnergyPumpLaw", "cyclic_coordinates"]

#: Hand over to LQR once every posture angle is within this of x*'s, wrapped (rad).
DEFAULT_CATCH = 0.3
#: Floor on |y| in the pumping term (rad/s): the push a start at rest gets.
DEFAULT_KICK = 0.1
#: Natural frequency (rad/s) of the critically damped pull on a cyclic actuated joint (K_p on a
#: prismatic one, K_d on every one): below a pendulum's own swing, so it does not undo the pump,
#: yet enough to keep a cart near its target and a wheel or an arm from spinning up.
CART_FREQUENCY = 2.0
#: The default gain asks for the full effort while the energy gap exceeds this share of
#: |E* − E_rest| at 1 rad/s: the pump saturates over most of a swing, as Åström & Furuta's does.
SATURATED_SHARE = 0.1


def cyclic_coordinates(system, samples: int = 16, seed: int = 0) -> np.ndarray:
    """(nq,) bool: coordinates the potential does not depend on (|∂U/∂q_i| ≤ 1e-9 of the largest
    component, at `samples` seeded configurations of the training box): a cart on a level rail, a
    Furuta arm about the vertical, a balanced wheel."""
    nq = system.nq
    lo, hi = (np.asarray(b, float)[:nq] for b in system.domain)
    q = np.random.default_rng(seed).uniform(lo, hi, (samples, nq))
    grad = -np.asarray(system.f(np.concatenate([q, np.zeros_like(q)], axis=1)), float)[:, nq:]  # ṗ at rest = −∇U
    scale = max(float(np.abs(grad).max()), 1e-300)
    return np.abs(grad).max(axis=0) <= 1e-9 * scale


def _gains(system, joint: np.ndarray, cyclic_q: np.ndarray, gap: float, gain) -> dict:
    """The derived fields of `EnergyPumpLaw` (its docstring) for inputs acting on coordinates `joint` (m,)."""
    nq = system.nq
    effort = np.asarray(system.effort, float)
    if gain is None:
        k = np.where(np.isfinite(effort), effort, gap / 1.0) / (SATURATED_SHARE * gap)
    else:
        k = np.broadcast_to(np.asarray(gain, float), effort.shape).copy()
    cyclic = cyclic_q[joint]
    prismatic = np.array([system.joints[i].kind in ("prismatic", "analytic-linear") for i in joint], bool)
    M = np.asarray(system.mass_matrix(np.asarray(system.x_star, float)[:nq]), float)
    M_cc = M[joint, joint]
    r = np.setdiff1d(np.arange(nq), joint[cyclic])
    coupling = np.array([np.linalg.norm(M[j, r]) for j in joint[cyclic]])
    coupling = np.where(coupling > 1e-12 * M_cc[cyclic], coupling, M_cc[cyclic])
    w = CART_FREQUENCY
    return {
        "cyclic": cyclic,
        "posture": np.asarray(system.angle_mask, bool)[:nq] & ~cyclic_q,
        "coupling": coupling,
        "k": k,
        "kp": np.where(cyclic & prismatic, M_cc * w**2, 0.0),
        "kd": np.where(cyclic, 2.0 * M_cc * w, 0.0),
    }


@dataclass(frozen=True, eq=False)
class EnergyPumpLaw:
    """Energy-pumping swing-up with an LQR catch: ``law(x: (N, n)) -> (N, m)``, float64, x = (q, p).

    Parameters
    ----------
    system : the `System`; its Hamiltonian, effort limits and x* define the law.
    catch : hand over to saturated LQR once every posture angle is within this of x*'s (rad).
    kick : floor on |y| in the pumping term (rad/s).
    gain : (m,) k, N·m (or N) per J per rad/s; None: ``effort / (s |E* − E_rest| · 1 rad/s)`` with
        s = `SATURATED_SHARE` (an unlimited joint takes |E* − E_rest| / 1 rad as its effort: the
        torque that does the missing work over one radian).

    Attributes (derived)
    --------------------
    lqr : `LQRController` of the system (Q = I, R = I), saturated to the effort limits.
    e_star, e_rest : H(x*) and H(q_rest, 0) (J), q_rest = `resting_configuration`.
    cyclic : (m,) bool, inputs on cyclic joints (`cyclic_coordinates`). posture : (nq,) bool, the
        angles the catch reads. coupling : (c,) ‖M_cr(q*)‖ of each cyclic input (kg·m or kg·m²).
    k : (m,) pumping gain. kp : (m,), N/m: M_cc(q*)·ω² on prismatic cyclic joints; kd : (m,),
        N·s/m or N·m·s/rad: 2·M_cc(q*)·ω on cyclic joints; ω = `CART_FREQUENCY`, 0 elsewhere.
    """

    system: object = field(repr=False)
    catch: float = DEFAULT_CATCH
    kick: float = DEFAULT_KICK
    gain: np.ndarray | None = None
    lqr: LQRController = field(init=False, repr=False)
    e_star: float = field(init=False)
    e_rest: float = field(init=False)
    cyclic: np.ndarray = field(init=False)
    posture: np.ndarray = field(init=False)
    coupling: np.ndarray = field(init=False)
    k: np.ndarray = field(init=False)
    kp: np.ndarray = field(init=False)
    kd: np.ndarray = field(init=False)

    def __post_init__(self):
        system = self.system
        if not (self.catch > 0 and self.kick >= 0):
            raise IdapbcError(f"EnergyPumpLaw needs catch > 0 and kick ≥ 0, got catch={self.catch!r}, kick={self.kick!r}. Fix: pass positive values.")
        nq = system.nq
        e_star = float(system.hamiltonian(np.asarray(system.x_star, float)))
        e_rest = float(system.hamiltonian(np.concatenate([resting_configuration(system), np.zeros(nq)])))
        gap = abs(e_star - e_rest)
        if not gap > 1e-9 * max(1.0, abs(e_star)):
            raise IdapbcError(
                f"'{system.name}' rests at its target (H(x*) = H(q_rest, 0) = {e_star:.6g} J): there is nothing to swing up. "
                "Fix: use LQRController, or pick a target above the resting posture."
            )
        derived = _gains(system, self._joint(), cyclic_coordinates(system), gap, self.gain)
        derived.update(lqr=LQRController(system), e_star=e_star, e_rest=e_rest)
        for name, value in derived.items():
            object.__setattr__(self, name, value)

    def _joint(self) -> np.ndarray:
        """(m,) the coordinate each input acts on (B's columns pick joints)."""
        return np.argmax(np.asarray(self.system.B, float), axis=0)

    def near_target(self, x) -> np.ndarray:
        """(N,) bool: every posture angle of x (N, n) within `catch` of x*'s (wrapped): LQR acts."""
        system = self.system
        nq = system.nq
        dq = wrap_angles(np.asarray(x, float)[:, :nq] - np.asarray(system.x_star, float)[:nq], np.asarray(system.angle_mask, bool)[:nq])
        return (np.abs(dq[:, self.posture]) <= self.catch).all(axis=1)

    def energy_and_direction(self, x) -> tuple[np.ndarray, np.ndarray]:
        """The energy pumped E (N,), J, and the pumping direction y (N, m), rad/s or m/s, at x (N, n)
        (module docstring); E = H(x) and y = v_a when no input acts on a cyclic joint."""
        system = self.system
        x = np.asarray(x, float)
        joint = self._joint()
        q, v = system.split(x)
        y = v[:, joint].copy()
        if not self.cyclic.any():
            return np.asarray(system.hamiltonian(x), float), y
        M = np.asarray(system.mass_matrix(q), float)
        c = joint[self.cyclic]
        r = np.setdiff1d(np.arange(system.nq), c)
        v_r = v[:, r]
        E = 0.5 * np.einsum("ni,nij,nj->n", v_r, M[:, r][:, :, r], v_r) + np.asarray(system.potential(q), float)
        y[:, self.cyclic] = -np.einsum("nij,nj->ni", M[:, c][:, :, r], v_r) / self.coupling
        return E, y

    def pump(self, x) -> np.ndarray:
        """The pumping law with the pull on cyclic joints, saturated: (N, n) -> (N, m)."""
        system = self.system
        x = np.asarray(x, float)
        joint = self._joint()
        E, y = self.energy_and_direction(x)
        floored = np.where(y >= 0.0, 1.0, -1.0) * np.maximum(np.abs(y), self.kick)
        q, v = system.split(x)
        nq = system.nq
        dq = wrap_angles(q - np.asarray(system.x_star, float)[:nq], np.asarray(system.angle_mask, bool)[:nq])
        u = self.k * (self.e_star - E)[:, None] * floored - self.kp * dq[:, joint] - self.kd * v[:, joint]
        return system.saturate(u)

    def __call__(self, x) -> np.ndarray:
        """u (N, m): `pump` away from x*, saturated LQR within `catch` of it; (n,) -> (m,) too."""
        x = np.asarray(x, float)
        single = x.ndim == 1
        xb = x[None] if single else x
        u = np.empty((xb.shape[0], self.system.m))
        near = self.near_target(xb)
        if near.any():
            u[near] = self.system.saturate(self.lqr(xb[near]))
        if (~near).any():
            u[~near] = self.pump(xb[~near])
        return u[0] if single else u

    def __repr__(self) -> str:
        return f"EnergyPumpLaw(system={self.system.name!r}, catch={self.catch:g}, k={np.array2string(self.k, precision=3)})"
