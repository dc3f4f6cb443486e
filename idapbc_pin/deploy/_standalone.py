"""Neural IDA-PBC controller written by `idapbc-pin export`: standalone, numpy and Pinocchio only.

    import controller                       # this folder on sys.path (or load the file by its path)
    tau = controller.torque(q, v)           # (nv,) -> (nv,) or (N, nv) -> (N, nv); N·m or N per joint
    controller.EFFORT                       # (m,) limit of each actuated input, inf where none
    tau = controller.swing_up_torque(q, v, t)   # the swing-up manoeuvre from rest, t s after its command
    f = controller.SpeedFilter();  v_hat = f.update(q, v)   # speeds estimated from noisy ones, once per tick
    controller.JOINTS, controller.ACTUATED  # order of q, v and tau; order of u and EFFORT

q holds one coordinate per joint in JOINTS order (rad or m; a continuous joint's angle itself, not
its (cos, sin)), v the joint velocities (rad/s or m/s). The law (paper eq. tilde_u, g = [0; B]):

    q ← q* + wrap(q − q*) on the angles listed in controller.json's "wrap" (to within π of the target)
    x = (q, p), p = M(q) v;   f(x) = (v, C(q, v)ᵀv − ∇U(q) − D v)   (Pinocchio on robot.urdf)
    u = (BᵀB)⁻¹Bᵀ (f̃_d(x) − f(x))_p
    u ← u* + k(x) (u − u*)                                 (only if controller.json has a "fallback"
                  with an "inside_gain" k_in ≠ 1: the learned law scaled inside the training box;
                  k(x) = 1 + (k_in − 1) clip((r − r0) / (r1 − r0), 0, 1), r = max_i |δ_i| / s_i,
                  (r0, r1) its "inside_ramp"; k = k_in everywhere inside when r0 = r1 = 0)
    u ← u* − K δ  where some |δ_i| > s_i, δ = wrap(x − x*)   (only if controller.json has a "fallback":
                  the linear law the run uses outside its training box, half-widths s; its K is
                  the anchor's LQR gain times the fallback's "gain")
    u ← ū tanh(MLP(δ / s))  where some |δ_i| > inner_i        (instead, if the "fallback" has kind
                  "recovery": the run's recovery law outside an inner box; tanh hidden layers;
                  with a "level" c, only where also H_d(x) > c, H_d from desired_flow.py;
                  with "residual": u ← ū clip(clip(u / ū, ±1) + MLP(δ / s), ±1) there instead;
                  with labelled paths "X": u ← clip(U_k + K_k e_k, ±ū) there, the nearest path
                  point as for a tracking law below)
    u ← ū tanh(MLP(φ(δ)))  where some |δ_i| > box_i        (last, if the "fallback" has kind "swing_up":
                  the run's swing-up law outside its kept box (a null half-width is not read),
                  around the fallback it "wraps", above; φ(δ) = (sin δ_a, cos δ_a, δ_o / s_o): the
                  angles' sines and cosines, then the other components scaled; where it has a
                  nominal trajectory "X" instead, u ← clip(U_k + K_k e_k, ±ū) with e_k = wrap(x − X_k)
                  at the k that minimises ‖weight ⊙ e_k‖: a tracking law, which with a "funnel" ϱ
                  acts only where ‖weight ⊙ e_k‖ ≤ ϱ)
    u ← governed(u)                                         (if controller.json has a "governor": where the
                  energy E_g = ½ v_rᵀM_rr v_r + U(q) exceeds E* = U(q*) by more than "energy_margin"
                  of ΔE = E* − U(q_rest), no input adds energy and each brakes towards
                  −ū clip(w / "w_scale", ±1), w = (M⁻¹B)_rᵀM_rr v_r, fully "energy_band" ΔE further up;
                  where a joint k runs past "speed_start" of its "rating", no input speeds it up and
                  each brakes towards −ū clip(c / "w_scale", ±1), c = v_k (M⁻¹B)_k / max|(M⁻¹B)_k|,
                  fully at the rating: idapbc_pin.control.speed_governor)
    u ← clip(u, −EFFORT, EFFORT);   τ = B u

`swing_up_torque(q, v, t)` (when controller.json has a "manoeuvre"; the swing-up stage's manoeuvre
from rest): during knot k = ⌊t / knot⌋ of its nominal plan, u = clip(U(t) + K_k wrap(x − X(t)), ±ū)
with X(t) = X_k + (t / knot − k)(X_{k+1} − X_k) ("end" after the last knot) and U(t) the inputs
interpolated linearly between the knots' midpoints (U_0 before the first, the last after it), t
counted from the command at rest near the hanging posture; after the plan, `torque(q, v)`.

`SpeedFilter(**overrides)` (speed_filter.py, numpy only) is the steady-state Kalman filter the
robustness suite judges the law with: keep one per robot, call ``v_hat = f.update(q, v)`` once per
control tick on the measured q, v, and pass (q, v_hat) to `torque`; its settings (dt, the noise it
assumes) are controller.json's "speed_filter", and keyword arguments override them.

f̃_d = (J_d − R_d)∇H_d comes from desired_flow.py with weights.npz (the same function as
desired_flow.onnx); D is the URDF's joint damping. The folder's controller.json holds the rest.
`python controller.py` prints the torque at the target (≈ 0) and the latency of one state.
(In idapbc-pin this file is `idapbc_pin/deploy/_standalone.py`, copied verbatim by the export.)
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin

__all__ = ["ACTUATED", "EFFORT", "JOINTS", "ExportedController", "SpeedFilter", "swing_up_torque", "torque"]

HERE = Path(__file__).resolve().parent


def _load_sibling(directory: Path, stem: str):
    """The module in ``directory/<stem>.py``, whether or not the folder is on sys.path."""
    name = f"{__name__}_{stem}"
    spec = importlib.util.spec_from_file_location(name, directory / f"{stem}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


class ExportedController:
    """The exported law, loaded from a folder written by `idapbc-pin export`.

    Holds its own `pinocchio.Data`: use one instance per thread.
    """

    def __init__(self, directory=HERE):
        directory = Path(directory)
        meta = json.loads((directory / "controller.json").read_text())
        self.joints = tuple(meta["joints"])
        self.actuated = tuple(meta["actuated"])
        self.B = np.array(meta["B"], dtype=np.float64).reshape(len(self.joints), len(self.actuated))  # (nv, m)
        self.B_pinv_T = np.linalg.solve(self.B.T @ self.B, self.B.T).T  # ((BᵀB)⁻¹Bᵀ)ᵀ, (nv, m)
        self.effort = np.array([np.inf if e is None else e for e in meta["effort"]], dtype=np.float64)  # (m,)
        self.damping = np.array(meta["damping"], dtype=np.float64)  # (nv,)
        self.x_star = np.array(meta["x_star"], dtype=np.float64)  # (2 nv,)
        wrap = meta.get("wrap")  # (2 nv,) bool or null; only its q half can be True
        self.wrap = np.zeros(len(self.joints), bool) if wrap is None else np.array(wrap, bool)[: len(self.joints)]
        fallback = meta.get("fallback")  # null: the learned law everywhere
        self.swing = None  # a swing-up law around the fallback
        if fallback is not None and fallback.get("kind") == "swing_up":
            self.swing, fallback = _arrays(fallback), fallback.get("wraps")
        self.fallback = None if fallback is None else _arrays(fallback)
        self.manoeuvre = None if meta.get("manoeuvre") is None else _arrays(meta["manoeuvre"])
        self.guard = None if meta.get("rail_guard") is None else _arrays(meta["rail_guard"])  # exports before it had none
        self.governor = meta.get("governor")  # exports before it had none: no governor
        self.recovery = fallback is not None and fallback.get("kind") == "recovery"
        self.flow = _load_sibling(directory, "desired_flow").load_flow(directory / meta["weights"])
        self.model = pin.buildModelFromUrdf(str(directory / meta["urdf"]))
        self.data = self.model.createData()
        if tuple(self.model.names[1:]) != self.joints:
            raise ValueError(f"{meta['urdf']} has joints {list(self.model.names[1:])}, controller.json {list(self.joints)}")
        # minimal coordinate i is the joint whose velocity index is i; continuous joints store (cos, sin)
        joints = [self.model.joints[j] for j in range(1, self.model.njoints)]
        self._direct = [(j.idx_q, j.idx_v) for j in joints if j.nq == 1]
        self._circular = [(j.idx_q, j.idx_v) for j in joints if j.nq == 2]

    @property
    def nv(self) -> int:
        return len(self.joints)

    def configuration(self, q: np.ndarray) -> np.ndarray:
        """Minimal coordinates (N, nv) -> Pinocchio configurations (N, model.nq)."""
        out = np.empty((len(q), self.model.nq))
        for iq, iv in self._direct:
            out[:, iq] = q[:, iv]
        for iq, iv in self._circular:
            out[:, iq], out[:, iq + 1] = np.cos(q[:, iv]), np.sin(q[:, iv])
        return out

    def momentum_and_drift(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """p = M(q) v and ṗ = C(q, v)ᵀv − ∇U(q) − D v, the momentum half of f(x): (N, nv) ×2 -> (N, nv) ×2.

        (The position half of f is v itself; the control law does not use it, g = [0; B].)
        """
        model, data = self.model, self.data
        M = np.empty((len(q), self.nv, self.nv))
        p_dot = np.empty((len(q), self.nv))
        for k, qc in enumerate(self.configuration(q)):
            M[k] = pin.crba(model, data, qc)
            C = pin.computeCoriolisMatrix(model, data, qc, v[k])
            p_dot[k] = C.T @ v[k] - pin.computeGeneralizedGravity(model, data, qc)
        p_dot -= self.damping * v
        return np.einsum("nij,nj->ni", M, v), p_dot

    def control(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """u = (gᵀg)⁻¹gᵀ(f̃_d − f) = (BᵀB)⁻¹Bᵀ(f̃_d − f)_p before saturation: (N, nv) ×2 -> (N, m), N·m or N."""
        if self.wrap.any():
            q = q.copy()
            q_star = self.x_star[: self.nv][self.wrap]
            q[:, self.wrap] = q_star + np.pi - np.mod(np.pi - (q[:, self.wrap] - q_star), 2 * np.pi)
        p, p_dot = self.momentum_and_drift(q, v)
        x = np.concatenate([q, p], axis=1)
        u = (self.flow(x)[:, self.nv :] - p_dot) @ self.B_pinv_T
        u = u if self.fallback is None else self.outside_box(x, u)
        u = u if self.swing is None else self.swing_up(x, u)
        u = u if self.governor is None else self.governed(q, v, u)
        return u if self.guard is None else self.rail_guard(q, v, u)

    def governed(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """u (N, m) with the speed and energy governor's rule (module docstring; controller.json's "governor")."""
        gv = self.governor
        r = np.array(gv["energy_rows"], dtype=int)
        rating = np.array([np.inf if x is None else x for x in gv["rating"]], dtype=np.float64)
        effort, scale = np.array(gv["effort"], dtype=np.float64), float(gv["w_scale"])
        model, data = self.model, self.data
        rest = self.configuration(np.array([gv["q_star"], gv["q_rest"]], dtype=np.float64))
        e_star, e_rest = (pin.computePotentialEnergy(model, data, qc) for qc in rest)
        delta = e_star - e_rest if len(r) else 0.0
        with np.errstate(invalid="ignore", divide="ignore"):
            each = np.where(np.isfinite(rating), np.clip((np.abs(v) / rating - gv["speed_start"]) / (1.0 - gv["speed_start"]), 0.0, 1.0), 0.0)
        k = np.argmax(each, axis=1)
        s_v = each[np.arange(len(q)), k]
        s_e, w, c = np.zeros(len(q)), np.zeros_like(u), np.zeros_like(u)
        for n, qc in enumerate(self.configuration(q)):
            if delta <= 0 and s_v[n] == 0:
                continue
            M = pin.crba(model, data, qc)
            reach = np.linalg.solve(M, self.B)  # (nv, m): ∂v̇/∂u
            if delta > 0:
                Mv_r = M[np.ix_(r, r)] @ v[n, r]
                e_g = 0.5 * v[n, r] @ Mv_r + pin.computePotentialEnergy(model, data, qc)
                w[n] = reach[r].T @ Mv_r
                s_e[n] = min(max(((e_g - e_star) / delta - gv["energy_margin"]) / gv["energy_band"], 0.0), 1.0)
            if s_v[n] > 0:
                c[n] = v[n, k[n]] * reach[k[n]] / np.abs(reach[k[n]]).max()
        if not ((s_e > 0).any() or (s_v > 0).any()):
            return u
        speed = (s_v > 0)[:, None]
        u = np.where((speed & (u * c > 0)) | (~speed & (s_e[:, None] > 0) & (u * w > 0)), 0.0, u)
        brake = -effort * np.clip(np.where(speed, c, w) / scale, -1.0, 1.0)
        s = np.where(speed, np.where(w * c > 0, np.maximum(s_e, s_v)[:, None], s_v[:, None]), s_e[:, None])
        return (1.0 - s) * u + s * brake

    def rail_guard(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """u (N, m) with full braking on each rail where the cart is past an end less the margin, or heads
        for one it could no longer stop short of: k v² / (2 a_b) ≥ d, a_b the deceleration under full
        braking (ABA, joint damping), k the guard's "safety"."""
        g = self.guard
        j, a = g["coordinate"].astype(int), g["input"].astype(int)
        s, w = q[:, j], v[:, j]
        past = np.where(s > g["upper"], 1.0, np.where(s < g["lower"], -1.0, 0.0))
        toward = np.where(past != 0, past, np.sign(w))
        u_b = -toward * g["sign"] * g["effort"]
        brake_u = np.zeros_like(u)
        brake_u[:, a] = u_b
        tau = brake_u @ self.B.T - self.damping * v
        acc = np.stack([pin.aba(self.model, self.data, qc, v[k], tau[k]) for k, qc in enumerate(self.configuration(q))])[:, j]
        deceleration = -toward * acc
        room = np.where(toward > 0, g["upper"] - s, s - g["lower"])
        stop = np.where(deceleration > 1e-9, g["safety"] * w**2 / (2.0 * np.maximum(deceleration, 1e-9)), np.inf)
        brake = (past != 0) | ((w != 0) & (stop >= room))
        if not brake.any():
            return u
        u = u.copy()
        for i, col in enumerate(a):
            u[brake[:, i], col] = u_b[brake[:, i], i]
        return u

    def outside_box(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """On the rows of x (N, n) outside the fallback's box, u* − Kδ (linear) or the recovery law;
        u (N, m) elsewhere, scaled about u* by the linear fallback's inside gain."""
        fb = self.fallback
        d = x - fb["x_star"]
        d[:, fb["angle_mask"]] = np.pi - np.mod(np.pi - d[:, fb["angle_mask"]], 2 * np.pi)  # wrap to (−π, π]
        k_in = float(fb.get("inside_gain", 1.0))  # exports before it had none: 1
        if not self.recovery and k_in != 1.0:
            r0, r1 = fb.get("inside_ramp", (0.0, 0.0))  # exports before it had none: a constant gain
            r = (np.abs(d) / fb["half"]).max(axis=1)
            w = np.clip((r - r0) / (r1 - r0), 0.0, 1.0) if r1 > r0 else (r >= r0).astype(np.float64)
            u = fb["u_star"] + (1.0 + (k_in - 1.0) * w)[:, None] * (u - fb["u_star"])
        out = (np.abs(d) > fb["inner" if self.recovery else "half"]).any(axis=1)
        if self.recovery and "level" in fb:  # the IDA-PBC law also keeps {H_d ≤ level}
            out &= self.flow.energy(x) > fb["level"]
        if out.any():
            u = u.copy()
            u[out] = self.recovery_law(d[out], u[out]) if self.recovery else fb["u_star"] - d[out] @ fb["K"].T
        return u

    def recovery_law(self, d: np.ndarray, u: np.ndarray) -> np.ndarray:
        """For δ (N, n) and the learned law's u (N, m) -> (N, m): ū tanh(MLP(δ / s)), or with "residual"
        ū clip(clip(u / ū, ±1) + MLP(δ / s), ±1); W0, b0, W1, b1, … of controller.json's "fallback".
        A library of paths ("X") reads the nearest path point instead: clip(U_k + K_k e, ±ū)."""
        fb = self.fallback
        if "X" in fb:  # the labelled paths: the point nearest to x = x* + δ, and its gains
            return _nearest_point_law(d + fb["x_star"], fb)
        z, depth = d / fb["scale"], sum(1 for k in fb if k.startswith("W"))
        for k in range(depth - 1):
            z = np.tanh(z @ fb[f"W{k}"].T + fb[f"b{k}"])
        z = z @ fb[f"W{depth - 1}"].T + fb[f"b{depth - 1}"]
        if bool(fb.get("residual", False)):
            return fb["effort"] * np.clip(np.clip(u / fb["effort"], -1.0, 1.0) + z, -1.0, 1.0)
        return fb["effort"] * np.tanh(z)

    def swing_up(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """On the rows of x (N, n) outside the swing-up law's kept box, that law (ū tanh(MLP(φ(δ))), or
        the tracking law at the nearest nominal point); u (N, m) elsewhere."""
        sw = self.swing
        mask = sw["angle_mask"]
        d = x - sw["x_star"]
        d[:, mask] = np.pi - np.mod(np.pi - d[:, mask], 2 * np.pi)  # wrap to (−π, π]
        out = (np.abs(d) > sw["box"]).any(axis=1)  # an unread component's null reads as nan: never outside
        if not out.any():
            return u
        if "X" in sw:  # a tracking law: the nominal point nearest to x, and its gains, within its funnel
            k, e = _nearest_point(x[out], sw)
            funnel = float(sw.get("funnel", np.nan))  # null (none) reads as nan
            near = ((e * sw["weight"]) ** 2).sum(axis=1) <= funnel ** 2 if np.isfinite(funnel) else np.ones(len(k), bool)
            u = u.copy()
            rows = np.flatnonzero(out)[near]
            u[rows] = _point_law(sw, k[near], e[near])
            return u
        z = np.concatenate([np.sin(d[out][:, mask]), np.cos(d[out][:, mask]), d[out][:, ~mask] / sw["scale"][~mask]], axis=1)
        depth = sum(1 for k in sw if k.startswith("W"))
        for k in range(depth - 1):
            z = np.tanh(z @ sw[f"W{k}"].T + sw[f"b{k}"])
        u = u.copy()
        u[out] = sw["effort"] * np.tanh(z @ sw[f"W{depth - 1}"].T + sw[f"b{depth - 1}"])
        return u

    def torque(self, q, v) -> np.ndarray:
        """τ = B clip(u, ±EFFORT): (N, nv) ×2 -> (N, nv), or (nv,) ×2 -> (nv,)."""
        q, v = np.asarray(q, dtype=np.float64), np.asarray(v, dtype=np.float64)
        single = q.ndim == 1
        q, v = (q[None], v[None]) if single else (q, v)
        if q.shape != v.shape or q.ndim != 2 or q.shape[1] != self.nv:
            raise ValueError(f"q and v must both have shape ({self.nv},) or (N, {self.nv}), got {q.shape} and {v.shape}")
        u = np.minimum(np.maximum(self.control(q, v), -self.effort), self.effort)  # = np.clip, faster
        tau = u @ self.B.T
        return tau[0] if single else tau


    def swing_up_torque(self, q, v, t: float) -> np.ndarray:
        """τ of the swing-up manoeuvre t s after its command (`torque(q, v)` after its plan, or
        without one): (N, nv) ×2 -> (N, nv), or (nv,) ×2 -> (nv,)."""
        mv = self.manoeuvre
        if mv is None or t >= len(mv["X"]) * float(mv["knot"]) - 1e-12:
            return self.torque(q, v)
        q, v = np.asarray(q, dtype=np.float64), np.asarray(v, dtype=np.float64)
        single = q.ndim == 1
        q, v = (q[None], v[None]) if single else (q, v)
        M = np.stack([pin.crba(self.model, self.data, qc) for qc in self.configuration(q)])
        k = min(int(np.floor(t / float(mv["knot"]) + 1e-9)), len(mv["X"]) - 1)
        after = mv["X"][k + 1] if k + 1 < len(mv["X"]) else mv["end"]
        nominal = mv["X"][k] + min(max(t / float(mv["knot"]) - k, 0.0), 1.0) * (after - mv["X"][k])  # between the knots
        mids = np.arange(len(mv["U"])) + 0.5  # the inputs between the knots' midpoints, held beyond the first and last
        feed = np.array([np.interp(t / float(mv["knot"]), mids, u) for u in mv["U"].T])
        e = np.concatenate([q, np.einsum("nij,nj->ni", M, v)], axis=1) - nominal
        e[:, mv["angle_mask"]] = np.pi - np.mod(np.pi - e[:, mv["angle_mask"]], 2 * np.pi)
        u = np.clip(feed + e @ mv["K"][k].T, -mv["effort"], mv["effort"])
        tau = np.minimum(np.maximum(u, -self.effort), self.effort) @ self.B.T
        return tau[0] if single else tau


def _nearest_point(x: np.ndarray, law: dict) -> tuple[np.ndarray, np.ndarray]:
    """(k (N,), e_k (N, n)): the point X_k of `law` nearest to each state x (N, n) by the distance
    ‖weight ⊙ e_k‖, e_k = wrap(x − X_k)."""
    e = x[:, None, :] - law["X"][None]
    e[..., law["angle_mask"]] = np.pi - np.mod(np.pi - e[..., law["angle_mask"]], 2 * np.pi)
    k = np.argmin(((e * law["weight"]) ** 2).sum(axis=-1), axis=1)
    return k, e[np.arange(len(k)), k]


def _nearest_point_law(x: np.ndarray, law: dict) -> np.ndarray:
    """clip(U_k + K_k e_k, ±ū) at the point X_k of `law` nearest to each state x (N, n)
    (`_nearest_point`): a tracking law, or a recovery law's library of paths -> (N, m)."""
    return _point_law(law, *_nearest_point(x, law))


def _point_law(law: dict, k: np.ndarray, e: np.ndarray) -> np.ndarray:
    """clip(U_k + K_k e, ±ū) for point indices k (N,) and errors e (N, n) -> (N, m)."""
    return np.clip(law["U"][k] + np.einsum("nij,nj->ni", law["K"][k], e), -law["effort"], law["effort"])


def _arrays(fallback: dict) -> dict:
    """controller.json's "fallback" (or the one a swing-up law "wraps") as arrays by name (angle_mask boolean)."""
    return {k: np.array(v, dtype=bool if k == "angle_mask" else np.float64) for k, v in fallback.items() if k not in ("kind", "wraps")}


_CONTROLLER = ExportedController(HERE)
JOINTS, ACTUATED, EFFORT = _CONTROLLER.joints, _CONTROLLER.actuated, _CONTROLLER.effort
torque = _CONTROLLER.torque
swing_up_torque = _CONTROLLER.swing_up_torque
_FILTER_SETTINGS = json.loads((HERE / "controller.json").read_text()).get("speed_filter") or {}


def SpeedFilter(**overrides):
    """A fresh speed filter with controller.json's settings (keyword arguments override them)."""
    return _load_sibling(HERE, "speed_filter").SpeedFilter(**(_FILTER_SETTINGS | overrides))


if __name__ == "__main__":
    import time

    q_star, v_zero = _CONTROLLER.x_star[: _CONTROLLER.nv], np.zeros(_CONTROLLER.nv)
    print("joints:", ", ".join(JOINTS), "| actuated:", ", ".join(ACTUATED), "| effort:", EFFORT)
    print("torque at the target (≈ 0):", torque(q_star, v_zero))
    times = []
    for _ in range(1000):
        t0 = time.perf_counter()
        torque(q_star + 0.1, v_zero + 0.2)
        times.append(time.perf_counter() - t0)
    print(f"one state: median {np.median(times) * 1e3:.3f} ms, p99 {np.quantile(times, 0.99) * 1e3:.3f} ms")
