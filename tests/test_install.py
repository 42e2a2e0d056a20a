"""A wheel built from the repo carries the shaders and assets and works from outside the repo."""
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(REPO)], check=True)
    (path,) = out.glob("puppet-*.whl")
    return path


def test_wheel_contains_shaders_and_assets(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in ["puppet/shaders/puppet.vert", "puppet/shaders/skin.frag", "puppet/shaders/mouth.frag", "puppet/shaders/overlay.vert",
                 "puppet/assets/mean_face.txt", "puppet/assets/demo/character.png",
                 "puppet/assets/demo/character_landmarks.txt", "puppet/assets/demo/speech.wav"]:
        assert name in names, name


@pytest.mark.slow
def test_installed_wheel_renders_the_demo_outside_the_repo(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    venv.create(env_dir, system_site_packages=True, with_pip=True)
    python = env_dir / "bin" / "python"
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--force-reinstall", str(wheel)], check=True)
    where = subprocess.run([str(python), "-c", "import puppet; print(puppet.__file__)"], cwd=tmp_path, check=True, capture_output=True, text=True)
    assert str(env_dir) in where.stdout
    result = subprocess.run([str(env_dir / "bin" / "puppet"), "render", "--demo", "-o", "demo.mp4", "--size", "128", "-q"], cwd=tmp_path, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "demo.mp4").stat().st_size > 10_000
