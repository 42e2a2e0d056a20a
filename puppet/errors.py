"""The one exception type users see, and the one warning type: the CLI prints each message as a single line."""


class PuppetError(Exception):
    """Bad input or an impossible request; the message says what is wrong and what to do."""


class PuppetWarning(UserWarning):
    """Something the user should know that does not stop the work; the CLI prints it as one line."""


class NoFaceError(PuppetError):
    """Face detection found no face (the rig editor then starts from a face placed in the middle)."""


def reason(error: Exception) -> str:
    """The one-line reason an OS or FFmpeg error gives, without errno and file-name clutter."""
    return getattr(error, "strerror", None) or str(error)
