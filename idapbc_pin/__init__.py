"""idapbc-pin: Neural IDA-PBC for underactuated robots, with port-Hamiltonian models from URDF.

Public API (DESIGN §6)::

    import idapbc_pin as ip
    sys = ip.load_system("cartpole")                    # zoo name, built-in name, URDF path, erd:<stem>
    sys.f(x); sys.df_dx(x); sys.g(x); sys.g_perp(x)     # batched over a leading dimension
    run = ip.train(sys, ip.TrainConfig.fast(), out="runs/cartpole")
    ctrl = run.controller; ip.simulate(sys, ctrl, x0, T=20.0); ip.view(run)

The torch- and meshcat-based parts load on first use, so `idapbc-pin inspect` starts quickly.
"""

from importlib import import_module

from .errors import IdapbcError
from .system import System, load_system

__version__ = "0.1.0"

_LAZY = {
    "TrainConfig": "config",
    "Run": "train",
    "train": "train",
    "load_run": "train",
    "LQRController": "simulate",
    "simulate": "simulate",
    "roa": "simulate",
    "evaluate_run": "evaluate",
    "certify": "certify",
    "figure": "report",
    "report": "report",
    "robustness_table": "robustness",
    "perturbed_system": "robustness",
    "run_batch": "batch",
    "view": "view",
    "write_html": "view",
}

__all__ = ["IdapbcError", "System", "load_system", *_LAZY]


def __getattr__(name):
    if name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'idapbc_pin' has no attribute '{name}'")


def __dir__():
    return sorted(__all__)
