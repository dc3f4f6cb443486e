"""The true plant, the integrator and the judge: closed-loop rollouts and their verdicts.

One concept per module, in the order a rollout uses them:

* `states`: evaluation boxes around x* (`scaled_box`) and seeded uniform initial states.
* `judge`: the true plant in (q, v) (Pinocchio's forward dynamics, or the closed form).
* `mujoco_plant`: `mujoco_judge`, the same system judged by MuJoCo (an independent engine, optional).
* `mujoco_rows`: `MujocoRowPlants`, the robustness suite's varied plants judged by MuJoCo.
* `limits`: the input bound a rollout applies (effort limits, saturation), `input_limits`.
* `step`: `judge_step`, the judge's step and control period (2 ms, or shorter for a loop stiffer at
  x*), and `horizon`.
* `integrate`: the closed-loop vector field, RK4 / RK45 steps, `simulate`.
* `trajectory`: `Trajectory`, what `simulate` returns.
* `metrics`: the judge's verdicts on a `Trajectory`: success, settling time, equilibrium offset,
  peak input.
* `compare`: `compare_laws`, candidate laws judged from the same states (every gate uses it).
* `leaderboard`: the RealAIGym tip test and v2 score of a swing-up (`tip_swingup_times`, `row_score`).
* `drive`: the RealAIGym global test's reset drive (upstream's PID with gravity compensation,
  `pid_drive`) and the states it releases the robot in (`drive_release_states`).

Scores built on these verdicts (ROA, radius, paired comparison, invariant share) live in
`idapbc_pin.evaluation`.
"""
