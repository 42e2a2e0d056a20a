"""puppet: make any portrait talk.

    import puppet
    pip = puppet.load("cartoon.png", landmarks="cartoon_landmarks.txt")
    puppet.render(pip, "speech.wav", "talk.mp4")
"""
import os

# numpy's OpenBLAS keeps its threads spinning after each matrix product, on the cores that onnxruntime
# and the renderer need; puppet's products are small, so one thread does them (the two networks files
# use ran at 142× real time beside spinning threads, 205× without). Takes effect where puppet is
# imported before numpy, as in the `puppet` command.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from puppet.bundle import Puppet, load, save
from puppet.errors import PuppetError
from puppet.video import VideoOptions, render

__version__ = "0.1.0"
__all__ = ["Puppet", "PuppetError", "VideoOptions", "load", "render", "save"]
