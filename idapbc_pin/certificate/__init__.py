"""The paper's conditions checked on dense samples: a sampled certificate, not a proof.

* `terms`: the pointwise quantities (H_d, ∇H_d, J_d, R_d, μ, ξ, Ḣ_d, ∇²H_d, eigenvalues at x*).
* `checks`: each condition as a function of the samples.
* `baseline`: the same sublevel test on the LQR baseline's δᵀSδ (its certified share).
* `result`: `Certificate` and its parts, verdicts, table and JSON.
* `certify`: `certify` (a run, a run directory or a controller → `Certificate`, certificate.json).
"""
