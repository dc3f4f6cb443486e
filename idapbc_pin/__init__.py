"""idapbc-pin: Neural IDA-PBC for underactuated robots, with port-Hamiltonian models from URDF.

Public API (DESIGN §6)::

    import idapbc_pin as ip
    sys = ip.load_system("cartpole")                    # zoo name, built-in name, URDF path, erd:<stem>
    sys.f(x); sys.df_dx(x); sys.g(x); sys.g_perp(x)     # batched over a leading dimension
"""

from .config import TrainConfig
from .errors import IdapbcError
from .simulate import LQRController, roa, simulate
from .system import System, load_system
from .train import Run, load_run, train
from .view import view, write_html

__all__ = ["IdapbcError", "LQRController", "Run", "System", "TrainConfig", "load_run", "load_system", "roa", "simulate", "train", "view", "write_html"]
__version__ = "0.1.0"
