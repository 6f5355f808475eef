import os
from pathlib import Path

import pytest

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# Tests never write into the user's compilation cache; the cache tests use their own folder.
os.environ.setdefault("GPJAX_COMPILATION_CACHE", "off")

SHARED = Path(__file__).resolve().parents[2] / "shared"


@pytest.fixture
def silverbox_dir():
    """The Silverbox data in ../shared; skipped where absent, a failure on CI."""
    path = SHARED / "data" / "silverbox"
    if not path.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"{path} is missing on CI; the shared data must be beside the checkout")
        pytest.skip(f"{path} not present (the Silverbox data lives in ../shared)")
    return path
