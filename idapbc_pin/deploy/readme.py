"""README.md of an exported controller: what the files are and how to run the law on a robot."""

from __future__ import annotations

import math

__all__ = ["deploy_readme"]


def _joint_table(record: dict) -> str:
    effort = dict(zip(record["actuated"], record["effort"]))
    rows = ["| # | joint | kind | actuated (u index) | effort limit |", "|---|---|---|---|---|"]
    for k, (name, kind) in enumerate(zip(record["joints"], record["joint_kinds"])):
        if name in effort:
            limit = effort[name]
            act = str(record["actuated"].index(name))
            limit = "none" if limit is None or not math.isfinite(limit) else f"{limit:g}"
        else:
            act, limit = "no", "—"
        rows.append(f"| {k} | {name} | {kind} | {act} | {limit} |")
    return "\n".join(rows)


_BODY = """\
## Files

| file | what |
|---|---|
| `controller.py` | `torque(q, v) -> tau`, the whole law; needs only `numpy` and `pin` (Pinocchio) |
| `desired_flow.py`, `weights.npz` | the learned f̃_d(x) in numpy ({dtype}), read by `controller.py` |
| `controller.json` | joint order, actuated joints, B, target x*, effort limits (`null` = none), damping |
| `robot.urdf` | the model the controller was trained on; `controller.py` recomputes f(x) from it |
{onnx_row}
## The law

With q the joint positions (one number per joint, order below; a continuous joint's angle itself,
not its cos/sin) and v the joint velocities:

    q    ← q* + wrap(q − q*)  on the angles of controller.json's "wrap" (to within π of q*)
    x    = (q, p),  p = M(q) v                                    (state, n = {n})
    f(x) = (v, C(q, v)ᵀ v − ∇U(q) − D v)                         (open-loop drift, Pinocchio)
    f̃_d  = (J_d − R_d) ∇H_d (x)                                   (learned, desired_flow / ONNX)
    u    = (BᵀB)⁻¹Bᵀ [f̃_d − f]_p
{fallback_line}    u    ← clip(u, −effort, effort),   τ = B u

`[·]_p` is the momentum half (last {nv} entries). Target x* = {x_star}. wrap(a) = a − 2π·round(a/2π):
a pendulum one turn away from the target is at the target; f is periodic in the angles, the learned
f̃_d is not, so feed the ONNX graph the wrapped state too.
{fallback_text}
{joints}

## Python

    pip install numpy pin
    python controller.py          # prints τ at the target (≈ 0) and the time per state

    import sys; sys.path.insert(0, "path/to/this/folder")
    import controller
    tau = controller.torque(q, v)   # (nv,) -> (nv,) or (N, nv) -> (N, nv); N·m or N

## A 1 kHz loop

`torque` takes about 0.1–0.2 ms per state on one desktop core (`python controller.py` measures it
here). Keep numpy's BLAS on one thread (`OPENBLAS_NUM_THREADS=1` or `OMP_NUM_THREADS=1`) and build
the controller once, outside the loop:

    import time, controller
    period = 1e-3
    speeds = controller.SpeedFilter(dt=period)     # one per robot: it keeps its state between ticks
    next_tick = time.perf_counter()
    while running:
        q, v = robot.read_joint_state()            # in controller.JOINTS order
        robot.write_joint_effort(controller.torque(q, speeds.update(q, v)))
        next_tick += period
        time.sleep(max(0.0, next_tick - time.perf_counter()))

`SpeedFilter` (speed_filter.py, numpy only) estimates the speeds from the measured positions and
noisy speeds, a steady-state Kalman filter per joint; `idapbc-pin robustness` judges the law with
it. It assumes positions precise to about 1e-4 rad: with coarser encoders pass
`position_noise=` (rad) their resolution.

Python's sleep jitters by tens of µs; where the period must hold, run the law in C++ (below).

## ROS 2

**rclpy node.** Subscribe to `sensor_msgs/JointState`, reorder by name into `controller.JOINTS`,
publish the torques as `std_msgs/Float64MultiArray` to an effort-interface
`forward_command_controller` (ros2_control's `effort_controllers/JointGroupEffortController`):

    import numpy as np, rclpy, controller
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    class IdaPbc(Node):
        def __init__(self):
            super().__init__("idapbc")
            self.pub = self.create_publisher(Float64MultiArray, "/effort_controller/commands", 1)
            self.create_subscription(JointState, "/joint_states", self.step, 1)

        def step(self, msg):
            index = [msg.name.index(j) for j in controller.JOINTS]
            q = np.array(msg.position)[index]; v = np.array(msg.velocity)[index]
            tau = controller.torque(q, v)
            self.pub.publish(Float64MultiArray(data=[float(tau[controller.JOINTS.index(a)]) for a in controller.ACTUATED]))

    rclpy.init(); rclpy.spin(IdaPbc())

The loop then runs at the rate of `/joint_states` (the joint_state_broadcaster's `update_rate`).

**ros2_control controller (C++), for a hard 1 kHz.** In `update()` read the position and velocity
state interfaces, then:

1. Pinocchio C++ on `robot.urdf` (`pinocchio::urdf::buildModel`): map q to Pinocchio's
   configuration (a continuous joint takes (cos θ, sin θ)); `crba` (it fills the upper triangle
   of `data.M`: symmetrise before p = M v); `computeCoriolisMatrix(model, data, q, v)` and
   `computeGeneralizedGravity(model, data, q)`; f = (v, Cᵀv − g − D v) with D from controller.json.
2. ONNX Runtime C++ on `desired_flow.onnx`: one `Ort::Session` created in `on_configure`, input
   `x` = (q, p) as a 1 × {n} {dtype} tensor, output `f_d`.
3. u = (BᵀB)⁻¹Bᵀ (f_d − f) on the momentum rows (outside the training box, the linear law of
   controller.json's "fallback" instead, if it has one), clip to the limits, write the actuated
   joints' effort command interfaces.

Check the C++ side against `controller.torque` on a few recorded states before closing the loop.
"""


def deploy_readme(record: dict) -> str:
    """README.md text for the folder described by `record` (controller.json's contents)."""
    nv = len(record["joints"])
    x_star = "(" + ", ".join(f"{v:g}" for v in record["x_star"]) + ")"
    title = f"# Neural IDA-PBC controller: {record['robot']}\n\nExported by `idapbc-pin export` from run `{record['run']}` ({record['checkpoint']} checkpoint).\n\n"
    onnx_row = (
        f"| `desired_flow.onnx` | f̃_d(x) alone, for ONNX Runtime (input `x` (N, {2 * nv}), output `f_d` (N, {2 * nv}), {record['dtype']}) |\n"
        if record.get("onnx")
        else ""
    )
    fallback = record.get("fallback")
    swing = fallback if fallback is not None and fallback.get("kind") == "swing_up" else None
    fallback = fallback.get("wraps") if swing is not None else fallback
    line, text = _fallback_text(fallback)
    if swing is not None and "X" in swing:
        line += "    u    ← clip(U_k + K_k e_k, ±ū), e_k = wrap(x − X_k) nearest   where some |δ_i| > box_i  (the swing-up law)\n"
        text += ("\nOutside a box around x* (controller.json's \"fallback\" → \"box\"; null: a component not read) the run uses its swing-up law, a "
                 "torque plan from the resting posture to x* (nominal states \"X\" in (q, p), inputs \"U\") tracked by the gains \"K\" of a "
                 "time-varying LQR, read at the nominal point nearest to the state (distance weighted by \"weight\"; with a \"funnel\" ϱ, only "
                 "where that distance is at most ϱ; `idapbc-pin train --swing-up`), around the law it \"wraps\", above (`controller.py` applies it). It was kept because it brought more "
                 "simulated near-resting states to x* under the effort limits; no certificate covers it.\n")
    elif swing is not None:
        line += "    u    ← ū tanh(MLP(φ(δ)))  where some |δ_i| > box_i                        (the swing-up law)\n"
        text += ("\nOutside a box around x* (controller.json's \"fallback\" → \"box\"; null: a component not read) the run uses its swing-up law, a small "
                 "MLP fitted to torque plans from the resting posture (`idapbc-pin train --swing-up`); it sees the sines and cosines of "
                 "the angles and the other components scaled. Its weights are controller.json's \"fallback\", around the law it \"wraps\", "
                 "above (`controller.py` applies it). It was kept because it brought more simulated near-resting states to x* under the "
                 "effort limits; no certificate covers it.\n")
    if record.get("manoeuvre") is not None:
        text += ("\nFrom rest near the hanging posture, `controller.swing_up_torque(q, v, t)` runs the run's swing-up manoeuvre, t seconds "
                 "after its command: a nominal plan from rest (controller.json's \"manoeuvre\": states \"X\" in (q, p), inputs \"U\", one knot "
                 "of \"knot\" s each) tracked in time by the gains \"K\" of a time-varying LQR, then `torque(q, v)` after its end. It was kept "
                 "because, simulated under the effort limits, it held more near-resting states at x* than the law alone, or as many and "
                 "swung up better from rest (the RealAIGym leaderboard's v2 score: time, energy, torque, smoothness, speed); start it from rest, "
                 "and fall back to `torque(q, v)` if the robot is far from its nominal.\n")
    governor = record.get("governor")
    if governor is not None:
        rated = ", ".join(f"{record['joints'][j]} {r:g}" for j, r in enumerate(governor["rating"]) if r is not None) or "none"
        line += "    u    ← governed(u)  where E_g > E* + margin·ΔE or a joint nears its rating  (the speed and energy governor)\n"
        text += (f"\nThen a speed and energy governor (controller.json's \"governor\") keeps any of these laws from whirling the robot: where "
                 f"the energy E_g of the posture's coordinates exceeds the upright's E* by more than {governor['energy_margin']:g} of the "
                 "swing from rest to upright, or a joint runs past "
                 f"{governor['speed_start']:g} of its rated speed (URDF `<limit velocity>`: {rated}), no input adds energy (or that joint's speed) and each brakes, at "
                 f"the full effort {governor['energy_band']:g} of that swing further up or at the rating. Elsewhere the input is the law's.\n")
    guard = record.get("rail_guard")
    if guard is not None:
        ends = ", ".join(f"{record['joints'][j]} [{lo:g}, {hi:g}] m" for j, lo, hi in zip(guard["coordinate"], guard["lower"], guard["upper"]))
        line += "    u_j  ← −sign(v_j) ū_j  where k v_j² / (2 a_b) ≥ the distance to the end v_j heads for  (the rail guard)\n"
        text += (f"\nLast, a rail guard ({ends}: the rail's ends less a margin; controller.json's \"rail_guard\") brakes the cart at full "
                 "force wherever it could no longer stop before the end it heads for: a_b is the deceleration full braking gives at the "
                 f"state (Pinocchio's ABA, joint damping included), k = {guard['safety']:g}; past an end it pushes the cart back. "
                 "Elsewhere the input is the law's.\n")
    body = _BODY.format(dtype=record["dtype"], n=2 * nv, nv=nv, x_star=x_star, joints=_joint_table(record), onnx_row=onnx_row,
                        fallback_line=line, fallback_text=text)
    return title + body


def _fallback_text(fallback: dict | None) -> tuple[str, str]:
    """The law's line and paragraph for the run's recovery or linear law (controller.json's
    "fallback", or the one a swing-up law "wraps"); empty without one."""
    line, text = "", ""
    if fallback is not None and fallback.get("kind") == "recovery":
        level = f" and H_d(x) > {fallback['level']:.6g}" if "level" in fallback else ""  # the IDA-PBC law also keeps {H_d ≤ level}
        library = "X" in fallback
        law = ("clip(U_k + K_k e_k, ±ū)" if library else "ū clip(clip(u / ū, ±1) + MLP(δ / s), ±1)" if fallback.get("residual")
               else "ū tanh(MLP(δ / s))")
        line = f"    u    ← {law}  where some |δ_i| > inner_i{level},  δ = wrap(x − x*)  (the recovery law)\n"
        inner = "(" + ", ".join(f"{v:.4g}" for v in fallback["inner"]) + ")"
        if level:
            inner += f" and where H_d(x) > {fallback['level']:.6g} (H_d from desired_flow.py)"
        text = (
            f"\nOutside an inner box (half-widths {inner} around x*) the run uses its recovery law, "
            + ("the paths of torque plans within the limits (`idapbc-pin recover`), each with the gains of a time-varying LQR along it, "
               "read at the nearest point (e_k = wrap(x − X_k), the k that minimises ‖weight ⊙ e_k‖), instead of the IDA-PBC law: its arrays are "
               if library else "a small MLP fitted to torque plans within the limits (`idapbc-pin recover`), "
               + ("as a correction added to the IDA-PBC law's input" if fallback.get("residual") else "instead of the IDA-PBC law") + ": its weights are ")
            + "controller.json's \"fallback\" (`controller.py` applies it; the ONNX graph is f̃_d alone). It was kept because it "
            "brought more simulated states to x* under the effort limits; no certificate covers it.\n"
        )
    elif fallback is not None:
        line = "    u    ← u* − K δ   where some |δ_i| > s_i,  δ = wrap(x − x*)              (outside the training box)\n"
        half = "(" + ", ".join(f"{v:.4g}" for v in fallback["half"]) + ")"
        text = (
            f"\nOutside the training box (half-widths s = {half} around x*) the run uses the linear law of its LQR "
            f"anchor (gain × {fallback.get('gain', 1.0):g}) instead of the learned one: K and u* are controller.json's \"fallback\" (`controller.py` applies it; "
            "the ONNX graph is f̃_d alone). The networks were trained on the box only; training chose this law there "
            "because it brought more simulated states to x*.\n"
        )
        k_in = float(fallback.get("inside_gain", 1.0))
        r0, r1 = (float(r) for r in fallback.get("inside_ramp", (0.0, 0.0)))
        if k_in != 1.0:
            k = f"{k_in:g}" if r1 == 0 else "k(x)"
            line = f"    u    ← u* + {k}·(u − u*)                                          (inside the training box)\n" + line
            ramp = ("" if r1 == 0 else
                    f" The factor is ramped in: k(x) = 1 + ({k_in:g} − 1)·clip((r − {r0:g}) / ({r1:g} − {r0:g}), 0, 1) with "
                    "r = max_i |δ_i| / s_i (\"inside_ramp\"), so near x* the learned law acts as trained and keeps its "
                    "LQR-like linearisation.")
            text += (
                f"\nInside the training box the learned law is scaled by {k_in:g} about u* (controller.json's \"fallback\" → "
                "\"inside_gain\"), so under the effort limits it switches on its sign as the linear law does outside; "
                f"training chose it because it brought more simulated states to x* than the learned law as trained.{ramp}\n"
            )
    return line, text
