"""The control law and its networks (paper §IV-A): desired closed loop ẋ = (J_d − R_d)∇H_d.

* `energy` (H_d, convex with its minimum at x*), `icnn` (the input-convex network behind it),
  `interconnection` (J_d, skew), `damping` (R_d, positive definite), built from `layers` and
  `structure`; `nets`: `IdaPbcNets`, the three together with the input structure g, g⊥.
* `linear`: LQR and the anchor's exact local solution; `anchor`: the anchor a system and a config
  give; `baseline`: `LQRController`, the reference every learned law is compared with.
* `controller`: `Controller`, the law u = (gᵀg)⁻¹gᵀ(f̃_d − f) in numpy, and `OuterLaw`, the protocol
  of a law that replaces it where it does not act (`idapbc_pin.recovery`).
* `rail_guard`: `RailGuard`, full braking of a cart that could no longer stop before its rail's end,
  applied by `Controller` after every other law.
* `energy_pump`: `EnergyPumpLaw`, the classical energy-pumping swing-up with an LQR catch, the
  swing-up reference (`idapbc_pin.evaluation.swingup`).
* `desired_flow` and `_runtime`: f̃_d in numpy from frozen weights (run time and export).
"""
