"""Scores of closed loops, and the evaluation of a run against the LQR baseline.

* `roa`: `score` (one controller's rollouts → `ControllerScore`) and `roa` (several controllers
  from the same states → `RoaResult`).
* `paired`: `paired_comparison`, how sure a lead is (interval and McNemar's p on the states where
  two controllers disagree).
* `radius`: `roa_radius`, the largest scale of the training box at which 90 % of the states succeed.
* `invariance`: `invariant_share`, the share of the box whose trajectory succeeds without leaving
  it: the most any certificate of that loop (a sublevel set inside the box) could cover.
* `evaluate`: `evaluate_run`, ROA on the domain and the half box and both ROA radii, effort limits
  applied unless lifted (evaluation.json).
* `swingup`: `evaluate_swingup`, from hanging to upright under the torque limits: the holds verdict,
  the RealAIGym tip test and the leaderboard's v2 score of the hanging start (`idapbc_pin.sim.leaderboard`).
* `robustness`: perturbed judge plants, the measured-state sensor, `robustness_table` (robustness.json).
* `closed_loop`: `simulate_run`, the ``idapbc-pin simulate`` command (simulation.json; the figure
  is `idapbc_pin.reporting.simulation_figure`).
"""
