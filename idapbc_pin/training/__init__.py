"""Training the networks H_d, J_d, R_d (paper §IV-B) on a system.

* `train`: `train`, the trainer's front door: a run directory, epochs with a progress bar,
  checkpoints, the gate of the outer law (`idapbc_pin.recovery.box_gate`) and summary.json.
* `_trainer`: the trainer's state (networks, optimiser, adaptive weights) and its checkpoints.
* `loss`: the loss as a sum of named terms, each with its adaptive weight.
* `rollout`: the optional rollout epochs through the saturated loop, and their gate.
* `summary`: summary.json's entries (final terms, ε, eigenvalues at x*).
"""
