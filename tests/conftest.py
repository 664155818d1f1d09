import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


@pytest.fixture(scope="session")
def demo_dir(tmp_path_factory):
    """The rendered demo preset (one video), shared by the tests of a session."""
    from galileo.dataset import build

    out = tmp_path_factory.mktemp("demo")
    build("demo", out, seed=0, workers=1, progress=False)
    return out / "demo"
