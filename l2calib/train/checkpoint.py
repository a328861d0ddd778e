"""Checkpoints that let a killed run continue to exactly the result of an uninterrupted one."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import torch

from l2calib.errors import TrainingError

CHECKPOINT_NAME = "checkpoint.pt"


#: Settings a resumed run may change: budgets and bookkeeping, not the optimisation itself.
#: Settings a resumed run may change: budgets, and where the candidates are scored (the same
#: seed gives the same result with any number of workers, any executor and any Ray actors).
RESUMABLE_CHANGES = (
    "max_iterations", "max_evaluations", "checkpoint_every", "workers", "executor", "ray"
)  # fmt: skip


def recipe_fingerprint(recipe_data: dict[str, Any], data_ids: list[str]) -> str:
    """Hash of everything that must match for a resume to be exact (recipe and input data).

    Budgets may change on resume (e.g. to train longer); with ``lr_schedule: cosine`` a new
    budget changes the schedule from then on.
    """
    train = {k: v for k, v in recipe_data.get("train", {}).items() if k not in RESUMABLE_CHANGES}
    text = json.dumps({"recipe": {**recipe_data, "train": train}, "data": data_ids}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Writes ``state`` atomically (a crash mid-write never leaves a half checkpoint)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: Path, fingerprint: str) -> dict[str, Any]:
    """Reads a checkpoint and checks it belongs to this recipe and data."""
    if not path.is_file():
        raise TrainingError(
            f"{path}: no checkpoint to resume from",
            fix="run without --resume, or point --out at the directory of the killed run",
        )
    try:
        state = torch.load(path, weights_only=False)
    except Exception as exc:  # a truncated or foreign file
        raise TrainingError(
            f"{path}: unreadable checkpoint ({exc})",
            fix="delete it and start again without --resume",
        ) from None
    if state.get("fingerprint") != fingerprint:
        raise TrainingError(
            f"{path} was written for another recipe or other input data",
            fix="resume with the same recipe, --set overrides and bags, or start a new --out",
        )
    return state


def checkpoint_iterations(path: Path) -> int | None:
    """PPO iterations a checkpoint holds (``None`` if it cannot be read)."""
    try:
        return len(torch.load(path, weights_only=False)["outcome"].history)
    except Exception:  # only used to tell the user where a resume continues
        return None
