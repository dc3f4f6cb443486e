"""`export`: write a run's controller as a standalone folder (numpy + Pinocchio, and ONNX)."""

from __future__ import annotations

import argparse

from ..deploy.export import EXPORTED_FILES, export
from ._args import add_command, add_checkpoint_argument, add_run_argument

__all__ = ["add_export_command"]


def _cmd_export(args: argparse.Namespace) -> int:
    """Write RUN's controller into DIR: controller.py with torque(q, v) saturated at the effort
    limits (needs only numpy and pin), desired_flow.py + weights.npz, desired_flow.onnx (f̃_d
    with explicit derivatives), the URDF, controller.json and a README on wiring it into a 1 kHz
    loop or a ROS 2 node."""
    out = export(args.run, args.out, force=args.force, onnx=not args.no_onnx, checkpoint=args.checkpoint)
    files = [name for name in EXPORTED_FILES if (out / name).is_file()]
    print(f"wrote {out}: {', '.join(files)}")
    print(f"try it: python {out / 'controller.py'}   (needs only numpy and pin)")
    return 0


def add_export_command(subparsers) -> argparse.ArgumentParser:
    """Register ``idapbc-pin export RUN --out DIR`` on an argparse sub-parsers object."""
    p = add_command(subparsers, "export", _cmd_export, help="write a deployable controller: controller.py (numpy + Pinocchio), weights, ONNX f̃_d, README")
    add_run_argument(p, "run directory written by `idapbc-pin train` (a URDF robot)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write (created; must be empty unless --force)")
    p.add_argument("--force", action="store_true", help="overwrite the exported files in a non-empty DIR")
    add_checkpoint_argument(p, "export")
    p.add_argument("--no-onnx", action="store_true", help="skip desired_flow.onnx (no onnx/onnxscript needed)")
    return p
