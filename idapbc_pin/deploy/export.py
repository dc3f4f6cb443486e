"""`export`: a trained run as a folder a robot can run without idapbc-pin or torch.

The folder (``--out DIR``) holds::

    controller.py       torque(q, v) -> τ, saturated at EFFORT; numpy + Pinocchio only
    desired_flow.py     f̃_d = (J_d − R_d)∇H_d in numpy (`idapbc_pin.control.desired_flow`, copied)
    speed_filter.py     `SpeedFilter`, the speed estimate to run on the measurements first (`idapbc_pin.control.speed_filter`, copied)
    weights.npz         the networks' weights (`DesiredFlow.arrays`), in their dtype
    controller.json     joints, actuated joints, B, x*, effort limits, damping, the law outside the
                        training box (if the run uses one), dtype, provenance
    robot.urdf          the run's copy of the URDF: controller.py recomputes the plant's f(x) from it
    desired_flow.onnx   f̃_d(x) as an ONNX graph with explicit derivatives (`onnx_flow`)
    README.md           how to wire it into a 1 kHz loop or a ROS 2 node (`readme`)

Every file comes from one `DesiredFlow` snapshot of the run's networks, and each is written
atomically. Only robots with a URDF can be exported: the standalone law needs Pinocchio's f(x).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from .._io import atomic_write_bytes, write_json
from ..control import desired_flow, speed_filter
from ..errors import IdapbcError
from ..run import resolve_run
from .onnx_flow import onnx_model
from .readme import deploy_readme

__all__ = ["EXPORTED_FILES", "export"]

#: The files `export` writes; ``--force`` overwrites these and leaves anything else in DIR alone.
EXPORTED_FILES = ("controller.py", "desired_flow.py", "speed_filter.py", "weights.npz", "controller.json", "robot.urdf", "desired_flow.onnx", "README.md")

_STANDALONE = Path(__file__).with_name("_standalone.py")


def _run_urdf(run) -> Path:
    """The run's copy of its URDF; a built-in analytic system has none and is refused."""
    urdf = Path(run.path) / "robot.urdf"
    if not urdf.is_file():
        raise IdapbcError(
            f"export needs a URDF robot: run '{run.path}' was trained on '{run.system.name}', which has no robot.urdf "
            "(built-in analytic systems have no Pinocchio model to recompute f(x) on the robot). "
            "Fix: train on a zoo name, a .urdf path or erd:<stem>, then export that run."
        )
    return urdf


def _check_out(out: Path, force: bool) -> None:
    """Refuse a file, or an existing non-empty folder without ``force``."""
    if out.exists() and not out.is_dir():
        raise IdapbcError(f"the output '{out}' is a file, not a folder. Fix: pass a folder path (--out DIR).")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise IdapbcError(
            f"the output folder '{out}' exists and is not empty. Fix: pick a new folder, or pass --force (force=True) "
            "to overwrite the exported files in it."
        )


def _controller_record(run, flow, onnx: bool) -> dict:
    """controller.json: what controller.py needs besides the weights, and where they came from."""
    system = run.system
    return {
        "format": desired_flow.FORMAT,
        "robot": system.name,
        "run": str(Path(run.path).resolve()),
        "checkpoint": run.checkpoint,
        "joints": list(system.coordinate_names),
        "joint_kinds": [j.kind for j in system.joints],
        "actuated": list(system.actuated),
        "B": system.B,
        "effort": system.effort,  # inf -> null: no limit
        "damping": [j.damping for j in system.joints],
        "x_star": system.x_star,
        "wrap": None if run.nets.angle_mask is None else run.nets.angle_mask.cpu().numpy().tolist(),  # angles wrapped to within π of x*
        "fallback": None if run.fallback is None else run.fallback.to_json(),  # the linear law outside the training box
        "manoeuvre": None if run.manoeuvre is None else run.manoeuvre.to_json(),  # the swing-up manoeuvre from rest
        "rail_guard": None if run.controller.guard is None else run.controller.guard.to_json(),  # full braking near a rail's end
        "governor": None if run.controller.governor is None else run.controller.governor.to_json(),  # energy out past E* or a rating
        "speed_filter": speed_filter.SpeedFilter().to_json(),  # the settings controller.SpeedFilter() starts from
        "state_names": list(system.state_names),
        "dtype": str(flow.dtype),
        "urdf": "robot.urdf",
        "weights": "weights.npz",
        "onnx": "desired_flow.onnx" if onnx else None,
    }


def export(run_or_path, out, *, force: bool = False, onnx: bool = True, checkpoint: str | None = None) -> Path:
    """Write a deployable controller for a run into the folder `out`; returns its path.

    Parameters
    ----------
    run_or_path : a `Run`, or a run directory (loaded with `checkpoint`: 'last', the final weights, by default, or 'best').
    out : the folder to write (created if missing). An existing non-empty folder needs ``force``,
        which overwrites the files in `EXPORTED_FILES` and nothing else.
    onnx : also write desired_flow.onnx (needs the `export` extra: onnx, onnxscript).

    Raises
    ------
    IdapbcError
        Not a run directory, a damaged checkpoint, a system without a URDF, or a non-empty `out`.
    """
    run = resolve_run(run_or_path, checkpoint)
    urdf = _run_urdf(run)
    out = Path(out)
    _check_out(out, force)
    flow = run.controller.flow()
    onnx_bytes = onnx_model(flow) if onnx else None  # before anything is written: it can fail
    weights = io.BytesIO()
    np.savez(weights, **flow.arrays())
    atomic_write_bytes(out / "weights.npz", weights.getvalue())
    atomic_write_bytes(out / "robot.urdf", urdf.read_bytes())
    atomic_write_bytes(out / "desired_flow.py", Path(desired_flow.__file__).read_bytes())
    atomic_write_bytes(out / "speed_filter.py", Path(speed_filter.__file__).read_bytes())
    record = _controller_record(run, flow, onnx)
    write_json(out / "controller.json", record)
    if onnx_bytes is not None:
        atomic_write_bytes(out / "desired_flow.onnx", onnx_bytes)
    else:
        (out / "desired_flow.onnx").unlink(missing_ok=True)  # an earlier export's, with other weights
    atomic_write_bytes(out / "README.md", deploy_readme(record).encode())
    atomic_write_bytes(out / "controller.py", _STANDALONE.read_bytes())  # last: its presence marks a complete export
    return out
