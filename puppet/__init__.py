"""puppet: make any portrait talk.

    import puppet
    pip = puppet.load("cartoon.png", landmarks="cartoon_landmarks.txt")
    puppet.render(pip, "speech.wav", "talk.mp4")
"""
from puppet.bundle import Puppet, load, save
from puppet.errors import PuppetError
from puppet.video import VideoOptions, render

__version__ = "0.1.0"
__all__ = ["Puppet", "PuppetError", "VideoOptions", "load", "render", "save"]
