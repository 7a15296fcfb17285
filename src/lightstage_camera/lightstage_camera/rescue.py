"""Rescue files: what a run could not write where it was meant to go, kept to write later.

A captured pose that cannot be written (disk full, the pose appeared meanwhile) goes to a
rescue file (`save_rescued`) that `write_rescued` (``lightstage capture DIR --from-rescued
FILE``) writes into a capture folder later. The rescue folders and `save_in_rescue_dir`,
which keeps any other output (a trained artifact, evaluation results) the same way, are
`lightstage_physics.output_files`.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lightstage_physics.errors import DestinationError
from lightstage_physics.output_files import save_in_rescue_dir
from lightstage_physics.rig import Rig

from .capture_destination import check_destination, write_model

__all__ = ["RescuedModel", "save_rescued", "load_rescued", "write_rescued", "rescue_message"]

RESCUE_KIND = "lightstage-rescued-model"
RESCUE_VERSION = 1


@dataclass
class RescuedModel:
    """A captured pose that could not be written where it was meant to go."""
    root: Path
    label: str
    sample: str
    pose: str
    rig: Rig
    model: np.ndarray


def save_rescued(rescued: RescuedModel) -> Path:
    """Save a pose to the first rescue folder that takes it (an ``.npz`` that loads without
    pickle: the model and a JSON header). Raises OSError when none does."""
    header = json.dumps({"kind": RESCUE_KIND, "version": RESCUE_VERSION,
                         "root": str(Path(rescued.root).absolute()), "label": rescued.label,
                         "sample": rescued.sample, "pose": rescued.pose,
                         "rig": rescued.rig.to_dict()})
    stamp = time.strftime("%Y%m%d-%H%M%S")

    def write(path: Path) -> None:
        with open(path, "wb") as f:
            np.savez(f, model=np.asarray(rescued.model, np.float32), header=np.array(header))

    return save_in_rescue_dir(
        f"{rescued.label}.{rescued.sample}.{rescued.pose}.{stamp}.{os.getpid()}.npz", write)


def load_rescued(path) -> RescuedModel:
    """A rescue file written by `save_rescued`; DestinationError if it is not one."""
    path = Path(path).expanduser()
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json.loads(str(data["header"]))
            model = np.asarray(data["model"], np.float32)
        if header.get("kind") != RESCUE_KIND or header.get("version") != RESCUE_VERSION:
            raise ValueError(f"not a rescue file of version {RESCUE_VERSION}")
        rig = Rig.from_dict(header["rig"], source=str(path))
        return RescuedModel(Path(header["root"]), header["label"], header["sample"],
                            header["pose"], rig, model)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DestinationError(f"{path} is not a readable rescue file ({exc}); give the file "
                               "named in the capture's error message") from None


def write_rescued(path, root=None, *, overwrite: bool = False) -> Path:
    """Write a rescue file's pose into ``root`` (default: the folder it was meant for) as a
    capture would have, then delete the rescue file; returns the pose folder."""
    rescued = load_rescued(path)
    root = Path(root).expanduser() if root else rescued.root
    target = check_destination(root, rescued.label, rescued.sample, rescued.pose, rescued.rig,
                               overwrite=overwrite, rig_from_file=True)
    pose_dir = write_model(target, rescued.model, overwrite=overwrite)
    Path(path).expanduser().unlink()
    return pose_dir


def rescue_message(error: Exception, rescued: RescuedModel) -> str:
    """The message of a capture that could not be written, with where it was kept."""
    try:
        kept = save_rescued(rescued)
    except OSError as exc:
        return (f"{error}. The captured images could not be kept anywhere else either ({exc}): "
                "free space and capture the pose again")
    return (f"{error}. The captured images are kept in {kept}: fix that, then write them with "
            f"`lightstage capture {rescued.root} --from-rescued {kept}` instead of capturing "
            "again")
