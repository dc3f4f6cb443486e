"""Training configuration: a frozen dataclass whose field docstrings are the CLI's help.

Defaults are the paper's (Table I: 2000 epochs, 512 fresh uniform samples per epoch, networks
n×3×300, γ = 0.9999, α = 0.01, Adam), plus what this project adds on top (LQR anchor, decay and effort terms; docs/method.md).
The paper gives no learning rate: 5e-4 (docs/results-history.md). `TrainConfig.fast()` is the `--fast` preset.
"""

from __future__ import annotations

from dataclasses import dataclass
from numbers import Integral
from pathlib import Path

from ._settings import Settings, read_table
from .errors import IdapbcError

__all__ = ["TrainConfig", "FIELD_HELP"]

FIELD_HELP = {
    "epochs": "number of epochs (paper: 2000); each epoch draws fresh uniform samples of the domain",
    "samples": "uniform samples of the training box per epoch (paper: 512)",
    "width": "hidden width of every network (paper: 300)",
    "depth": "hidden layers of every network (paper: 3)",
    "lr": "Adam learning rate (the paper gives none). 5e-4 in both presets: a larger rate makes the paper-size "
    "networks close the loop worse (docs/results-history.md)",
    "gamma": "adaptive-weight decay γ in r_i ← γ r_i + α f_i / max_j f_j (paper: 0.9999)",
    "alpha": "adaptive-weight update rate α (paper: 0.01)",
    "form": "'anchored': networks pinned to the exact LQR solution at x* (locally exponentially stable by "
    "construction); 'free': the paper's free form (Bregman-shifted ICNN, skew NN, L Lᵀ + ρS)",
    "anchor_q": "state weight of the LQR anchor, Q = anchor_q·I (R = I; see `anchor_weight` for its units); larger values "
    "give a faster local loop (anchored form only). 0 = automatic: the largest of 10, 1, 0.1, 0.01 whose anchor has "
    "no pole faster than 15 1/s (a stiffer loop asks for torques the actuators saturate on); 1, the LQR baseline's "
    "weight, when the plant itself has a pole faster than 15 1/s (no weight can meet the cap then)",
    "anchor_cart": "multiplier of a prismatic joint's position weight in the anchor's Q (a cart on a rail: Q = anchor_q·I "
    "weighs a metre of cart like a radian of angle, which leaves the cart's return the loop's slowest mode); 0 = automatic: "
    "the first of 1, 3, 10, 30, 100 whose anchor has no pole slower than 2 1/s (nor faster than 15 1/s), else 1; robots "
    "without a prismatic joint, and the analytic models, are unaffected",
    "anchor_weight": "units of the anchor's LQR state weight: 'physical' Q = anchor_q·I in the state's own units (the LQR "
    "baseline's weight when anchor_q = 1), whatever `scaling` is; 'box' Q = anchor_q·diag(1/s²) under box scaling, "
    "which weights the light links' tiny momenta by 1/s² ≈ 1e4 and can leave a pole far slower than "
    "LQR's on robots with light links",
    "anchor_p": "Hessian P of H_d at x* (anchored form): 'box' solves A_clᵀP + PA_cl = −diag(1/half-width²) of the "
    "training box (well conditioned in box units), 'lyapunov' the same with −I, 'riccati' takes the Riccati solution, "
    "'fit' the Lyapunov matrix (of the same LQR loop) whose ellipsoid fills the largest share of the training box",
    "energy_input": "input of H_d's ICNN (anchored form): 'box' u = (x − x*)/s (s: the training box's half-widths), "
    "'anchor' u = S P (x − x*) in the anchor's metric, so the network part of f̃_d is (J0 − R0)∇ψ = A_cl S ∇_uψ, "
    "bounded by the anchor's own scale however badly conditioned P is",
    "damping": "where ρ injects damping: 'full' (ρI, the paper) or 'actuated' (only the actuated momentum rows)",
    "rho": "ρ ≥ 0 added as ρS to R_d during training (free form; anchored keeps 0 so R_d(x*) is the LQR R); "
    "raise it after training with `with_damping`",
    "kappa": "κ > 0 of the robustness residuals f_sd1, f_sd2 (κ < ρ when ρ > 0)",
    "epsilon": "level ε of H_ε (inside: matching; outside: dissipation); 0 = automatic, the "
    "`inside_fraction` quantile of H_d over each batch (so ε keeps a meaning whatever H_d's scale)",
    "scaling": "'none': the anchor's LQR weight is anchor_q·I and λ_max(P) = 1 in physical units, network increments of "
    "J_d, R_d in absolute units; 'box': everything in box units z = (x − x*)/s, s the training box's half-widths "
    "(anchor weight anchor_q·diag(1/s²), λ_max(SPS) = 1, increments of J_d and R_d scaled by s_i s_j), for robots "
    "whose coordinates have very different ranges (light links: momenta of 1e-3 next to angles of 1); 'auto': "
    "'box' when the largest half-width exceeds 20 × the smallest, else 'none'",
    "inside_fraction": "share of the samples inside H_ε when epsilon = 0 (automatic)",
    "decay_rate": "λ of the decay term Ḣ_d ≤ −λ H_d outside H_ε (1/s); < 0 = automatic "
    "(half the LQR anchor's local rate, or 0.5 1/s in the free form); 0 disables the term",
    "local_stability": "train the third-order term f_dm = ‖∂μ/∂x‖ on samples inside H_ε",
    "dtype": "'float64' or 'float32' for the networks (plant data is always computed in float64)",
    "device": "'cpu' or 'cuda' (or 'cuda:0' …); a GPU pays off for paper-size networks, not for the small fast preset; commands on a finished RUN load it on the CPU",
    "seed": "random seed (weights and samples); same seed, same machine → same weights",
    "threads": "torch CPU threads (1 avoids oversubscribing the cores when other work runs beside training)",
    "checkpoint_every": "epochs between 'last' checkpoints",
    "effort_term": "train the `effort` term: |u| beyond the actuators' effort limits, penalised on the samples of the "
    "largest sublevel set of H_d that stays in the box (the set a certificate with the saturated law can cover); "
    "no effect on robots without limits",
    "rollout_epochs": "the last K epochs train on the `rollout` term instead of the residuals: back-propagation through "
    "short Euler simulations of the true closed loop f + g·sat(u) (the plant's exact ∂f/∂x in the backward pass), from "
    "start states in the `rollout_box`, cost log(1 + ‖(x − x*)/s‖²) over the last `rollout_tail` seconds. 0 = off. "
    "Each such epoch simulates `rollout_samples` rollouts of rollout_horizon / rollout_step steps, far slower than a residual epoch",
    "rollout_samples": "rollouts per `rollout` epoch (start states drawn uniformly, fresh each epoch)",
    "rollout_horizon": "length T of each rollout (s)",
    "rollout_step": "explicit Euler step h of the rollouts (s)",
    "rollout_tail": "the cost is averaged over the last `rollout_tail` seconds of each rollout (s, ≤ rollout_horizon)",
    "rollout_box": "start states are drawn in x* + b·(X − x*), b = rollout_box times the training box X",
    "face_samples": "samples of the training box's faces per epoch (the level of the `effort` term's sublevel set)",
    "verification_terms": "opt-in: train the `set_decrease` and `set_coverage` terms, which ask H_d to decrease along the "
    "true saturated loop on its sublevel set in the verification box (`verification_scale` × the training box, angles "
    "within ±π) and that set to cover the training box: what `certify` certifies (idapbc_pin.training.verification). "
    "Each epoch then also evaluates the plant on `samples` states of that box",
    "verification_scale": "width of the verification box the `verification_terms` use, in training boxes about x* (as `certify --scale`)",
    "wrap_angles": "the control law evaluates the networks at the state whose angles (revolute and continuous joints) are "
    "wrapped to within π of the target, as the LQR baseline does: a pendulum that swings once round is not 2π away "
    "from upright. Without it the networks see angles far outside the box they were trained on",
    "fallback": "the law outside the training box: 'linear' switches to the LQR anchor's linear law u* − k·Kδ there "
    "(k: `fallback_gain`; the networks are trained on the box only, and a saturated swing leaves it), 'none' keeps the learned law everywhere, "
    "'auto' decides after training by simulating both with the effort limits from 100 states of the run's own (the "
    "fallback is used if it brings strictly more of them to x*; summary.json → fallback). Inside the box nothing changes",
    "fallback_gain": "gain factor k of the linear law outside the training box, u* − k·Kδ (K: the anchor's LQR gain); "
    "0 = automatic: 3 for a robot with effort limits, whose law there then saturates on most of its course and switches "
    "on the sign of Kδ like a bang-bang law (docs/results-history.md), and "
    "1 for a robot without limits (a stiffer linear law would only ask for larger torques)",
    "bounded_structure": "J_d and R_d see the state clamped to the training box: outside it they keep their values on the "
    "box's boundary (still skew / positive definite) instead of extrapolating their networks, where R_d's "
    "exponential diagonal would grow without bound at the speeds a saturated swing reaches. H_d is not clamped (its "
    "convexity is kept); inside the box nothing changes",
    "swing_up": "after training (and the recovery stage), fit a swing-up law from the resting posture to x* within the effort "
    "limits and keep it if simulation shows it helps (`idapbc-pin train --swing-up`; its numbers: SwingUpConfig, "
    "--swing-config); then judge the run from near-resting states beside saturated LQR and the energy-pumping law",
}


@dataclass(frozen=True)
class TrainConfig(Settings):
    """Neural IDA-PBC training settings (see `FIELD_HELP` for each field)."""

    _what, _table, _fix = "training config", "train", "see `idapbc-pin train --help`"

    epochs: int = 2000
    samples: int = 512
    width: int = 300
    depth: int = 3
    lr: float = 5e-4
    gamma: float = 0.9999
    alpha: float = 0.01
    form: str = "anchored"
    anchor_q: float = 0.0
    anchor_cart: float = 0.0
    anchor_p: str = "riccati"
    anchor_weight: str = "physical"
    scaling: str = "auto"
    energy_input: str = "anchor"
    damping: str = "full"
    rho: float = 0.0
    kappa: float = 0.01
    epsilon: float = 0.0
    inside_fraction: float = 0.1
    decay_rate: float = -1.0
    local_stability: bool = True
    dtype: str = "float64"
    device: str = "cpu"
    seed: int = 0
    threads: int = 1
    checkpoint_every: int = 50
    effort_term: bool = True
    face_samples: int = 64
    verification_terms: bool = False
    verification_scale: float = 4.0
    rollout_epochs: int = 0
    rollout_samples: int = 64
    rollout_horizon: float = 3.0
    rollout_step: float = 0.01
    rollout_tail: float = 1.0
    rollout_box: float = 0.5
    wrap_angles: bool = True
    bounded_structure: bool = True
    fallback: str = "auto"
    fallback_gain: float = 0.0
    swing_up: bool = False

    def __post_init__(self):
        checks = [
            (self.epochs >= 1, "epochs must be ≥ 1"),
            (self.samples >= 8, "samples must be ≥ 8"),
            (self.width >= 1 and self.depth >= 1, "width and depth must be ≥ 1"),
            (self.lr > 0, "lr must be > 0"),
            (0 < self.gamma < 1, "gamma must be in (0, 1)"),
            (self.alpha > 0, "alpha must be > 0"),
            (self.form in ("anchored", "free"), "form must be 'anchored' or 'free'"),
            (self.damping in ("full", "actuated"), "damping must be 'full' or 'actuated'"),
            (self.anchor_q >= 0, f"anchor_q must be > 0 (or 0 = automatic), got {self.anchor_q}"),
            (self.anchor_cart >= 0, f"anchor_cart must be > 0 (or 0 = automatic), got {self.anchor_cart}"),
            (self.anchor_p in ("box", "lyapunov", "riccati", "fit"), "anchor_p must be 'box', 'lyapunov', 'riccati' or 'fit'"),
            (self.anchor_weight in ("physical", "box"), "anchor_weight must be 'physical' or 'box'"),
            (self.scaling in ("auto", "none", "box"), "scaling must be 'auto', 'none' or 'box'"),
            (self.energy_input in ("box", "anchor"), "energy_input must be 'box' or 'anchor'"),
            (self.rho >= 0, f"rho (ρ) must be ≥ 0, got {self.rho}"),
            (self.kappa > 0, f"kappa (κ) must be > 0, got {self.kappa}"),
            (self.rho == 0 or self.kappa < self.rho, f"kappa (κ = {self.kappa}) must be < rho (ρ = {self.rho}): the paper needs κ ∈ (0, ρ)"),
            (self.epsilon >= 0, "epsilon must be ≥ 0 (0 = automatic)"),
            (0 < self.inside_fraction < 1, "inside_fraction must be in (0, 1)"),
            (self.dtype in ("float64", "float32"), "dtype must be 'float64' or 'float32'"),
            (isinstance(self.seed, Integral) and not isinstance(self.seed, bool) and self.seed >= 0, f"seed must be an integer ≥ 0, got {self.seed!r}"),
            (self.threads >= 1, "threads must be ≥ 1"),
            (self.checkpoint_every >= 1, "checkpoint_every must be ≥ 1"),
            (self.face_samples >= 1, "face_samples must be ≥ 1"),
            (self.verification_scale >= 1, f"verification_scale must be ≥ 1 (the box holds the training box), got {self.verification_scale}"),
            (0 <= self.rollout_epochs <= self.epochs, f"rollout_epochs must be in [0, epochs = {self.epochs}], got {self.rollout_epochs}"),
            (self.rollout_samples >= 1, "rollout_samples must be ≥ 1"),
            (0 < self.rollout_step <= self.rollout_horizon, "rollout_step and rollout_horizon must satisfy 0 < rollout_step ≤ rollout_horizon"),
            (0 < self.rollout_tail <= self.rollout_horizon, "rollout_tail must be in (0, rollout_horizon]"),
            (0 < self.rollout_box <= 2, "rollout_box must be in (0, 2]"),
            (self.fallback in ("auto", "linear", "none"), "fallback must be 'auto', 'linear' or 'none'"),
            (self.fallback_gain >= 0, f"fallback_gain must be > 0 (or 0 = automatic), got {self.fallback_gain}"),
        ]
        for ok, message in checks:
            if not ok:
                raise IdapbcError(f"bad training config: {message}. Fix: change that value (CLI flag or config file).")

    @classmethod
    def fast(cls, **overrides) -> "TrainConfig":
        """The `--fast` preset: width 64 × 3 layers, float32, 1200 epochs; `overrides` replace any field.

        It trains several times faster than the paper's 3 × 300 networks and closes the loop about as
        well ("Fast preset vs paper setting" in docs/results-history.md).
        """
        base = {"width": 64, "depth": 3, "dtype": "float32", "epochs": 1200}
        return cls(**{**base, **overrides})

    @classmethod
    def file_values(cls, path: str | Path) -> dict:
        """The keys a config file sets, validated and typed (so a preset can be laid under them)."""
        data = read_table(path, cls._table, "config", cls._fix)
        config = cls.from_dict(data)
        return {k: getattr(config, k) for k in data}
