"""idapbc-pin: Neural IDA-PBC for underactuated robots, with port-Hamiltonian models from URDF.

Public API (see the README and docs/method.md)::

    import idapbc_pin as ip
    sys = ip.load_system("cartpole")                    # zoo name, built-in name, URDF path, erd:<stem>
    sys.f(x); sys.df_dx(x); sys.g(x); sys.g_perp(x)     # batched over a leading dimension
    run = ip.train(sys, ip.TrainConfig.fast(), out="runs/cartpole")
    ctrl = run.controller; ip.simulate(sys, ctrl, x0, T=20.0); ip.certify(run); ip.view(run)
    ip.export(run, "deploy/")                           # standalone controller (numpy + pin), ONNX f̃_d
    ip.recovery.recover(run)                            # weak actuators: a recovery law beside the IDA-PBC one
    ip.recovery.auto_recover(run)                       # ... only where saturated LQR leaves room (`train`'s default)

Evaluations apply the actuators' effort limits (``sys.effort``) to every controller unless
``limits=False``. The subpackages follow the data flow: model → control → sim → trajectory (plans,
their tracking, fits) → training → run → recovery (the stages) → evaluation → certificate → reporting / viewer → deploy → batch → cli.
"""

from .batch.runner import run_batch
from .certificate.certify import certify
from .config import TrainConfig
from .deploy.export import export
from .errors import IdapbcError
from .evaluation.evaluate import evaluate_run
from .reporting.report import figure, report
from .evaluation.robustness import perturbed_system
from .control.baseline import LQRController
from .control.speed_filter import SpeedFilter
from .sim.integrate import simulate
from .evaluation.invariance import invariant_share
from .sim.mujoco_plant import mujoco_judge
from .evaluation.paired import paired_comparison
from .evaluation.radius import roa_radius
from .evaluation.roa import roa
from .model import System, load_system
from .run import Run, load_run
from .training.train import train
from . import recovery, trajectory
from .viewer import view, write_html

__version__ = "0.1.0"

__all__ = [
    "IdapbcError",
    "LQRController",
    "Run",
    "SpeedFilter",
    "System",
    "TrainConfig",
    "certify",
    "evaluate_run",
    "export",
    "figure",
    "invariant_share",
    "load_run",
    "load_system",
    "mujoco_judge",
    "paired_comparison",
    "perturbed_system",
    "report",
    "roa",
    "roa_radius",
    "run_batch",
    "simulate",
    "train",
    "view",
    "write_html",
]
