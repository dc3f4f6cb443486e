"""Closed-loop simulation on the true plant, the DESIGN §4 metrics and the region of attraction.

One concept per module, in the order a rollout uses them:

* `states`: evaluation boxes around x* and seeded uniform initial states.
* `judge`: the true plant in (q, v) (Pinocchio's forward dynamics, or the closed form).
* `mujoco_plant`: `mujoco_judge`, the same system judged by MuJoCo (an independent engine, optional).
* `limits`: the input bound a rollout applies (effort limits, saturation), `input_limits`.
* `step`: `judge_step`, the judge's step and control period (2 ms, or shorter for a loop stiffer at x*).
* `integrate`: the closed-loop vector field, RK4 / RK45 steps, `simulate`.
* `trajectory`: `Trajectory`, what `simulate` returns.
* `metrics`: success, settling time, equilibrium offset, peak input of a `Trajectory`.
* `roa`: `score` (one controller's rollouts → `ControllerScore`) and `roa` (several controllers
  from the same states → `RoaResult`).
* `paired`: `paired_comparison`, how sure a lead is (interval and McNemar's p on the states where
  two controllers disagree).
* `radius`: `roa_radius`, the largest scale of the training box at which 90 % of the states succeed.
* `invariance`: `invariant_share`, the share of the box whose trajectory succeeds without leaving
  it: the most any certificate of that loop (a sublevel set inside the box) could cover.
"""
