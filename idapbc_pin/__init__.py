"""idapbc-pin: Neural IDA-PBC for underactuated robots, with port-Hamiltonian models from URDF.

Public API (DESIGN §6)::

    import idapbc_pin as ip
    sys = ip.load_system("cartpole")                    # zoo name, built-in name, URDF path, erd:<stem>
    sys.f(x); sys.df_dx(x); sys.g(x); sys.g_perp(x)     # batched over a leading dimension
"""

from .errors import IdapbcError
from .system import System, load_system

__all__ = ["IdapbcError", "System", "load_system"]
__version__ = "0.1.0"
