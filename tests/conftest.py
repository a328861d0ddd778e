from __future__ import annotations

import numpy as np
import pytest
import torch

torch.set_default_dtype(torch.float64)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(autouse=True, scope="session")
def _isolated_reference_cache(tmp_path_factory) -> None:
    """References are cached on disk; tests must neither reuse nor pollute a user's cache."""
    import os

    old = os.environ.get("L2CALIB_CACHE")
    os.environ["L2CALIB_CACHE"] = str(tmp_path_factory.mktemp("l2calib-cache"))
    yield
    if old is None:
        os.environ.pop("L2CALIB_CACHE", None)
    else:
        os.environ["L2CALIB_CACHE"] = old
