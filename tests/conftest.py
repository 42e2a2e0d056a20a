"""Shared fixtures: one headless GL context, the demo puppet, and the optional shared media."""
from pathlib import Path

import pytest

from puppet import bundle
from puppet.renderer import headless_context

# Third-party test media beside the repo (absent on a user's fresh clone: tests using it skip).
SHARED_MEDIA = Path(__file__).resolve().parents[2] / "shared" / "media"


@pytest.fixture(scope="session")
def gl():
    ctx = headless_context()
    yield ctx
    ctx.release()


@pytest.fixture(scope="session")
def demo():
    image, landmarks, _ = bundle.demo_files()
    return bundle.load(image, landmarks)


@pytest.fixture(scope="session")
def demo_speech():
    return bundle.demo_files()[2]


def shared(*parts: str) -> Path:
    """A path under ../shared/media, skipping the test when it is absent."""
    path = SHARED_MEDIA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} is not available")
    return path
