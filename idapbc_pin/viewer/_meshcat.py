"""meshcat, imported once with its server module (an optional-looking import that says how to fix it)."""

from __future__ import annotations

import warnings

from ..errors import IdapbcError

__all__ = ["import_meshcat"]


def import_meshcat():
    """The ``meshcat`` package, with ``meshcat.servers.zmqserver`` loaded.

    That server module imports a pyzmq module that warns it is deprecated; the warning is silenced.
    A missing or broken install raises `IdapbcError` with the install command.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            import meshcat
            import meshcat.servers.zmqserver  # noqa: F401
    except ImportError as exc:
        raise IdapbcError(f"the viewer needs meshcat ({exc}). Fix: pip install meshcat.") from None
    return meshcat
