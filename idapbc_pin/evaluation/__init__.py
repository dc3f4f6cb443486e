"""Closed-loop evaluation of a run against the LQR baseline.

* `evaluate`: `evaluate_run`, ROA on the domain and the half box and both ROA radii, effort limits
  applied unless lifted (evaluation.json).
* `robustness`: perturbed judge plants, the measured-state sensor, `robustness_table` (robustness.json).
* `closed_loop`: `simulate_run`, the ``idapbc-pin simulate`` command (simulation.json / .png).
"""
