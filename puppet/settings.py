"""Live settings a user tunes with hotkeys, kept per puppet between sessions.

A bundle keeps them in its own folder (`live.json`); a plain image or the demo keeps them under
the user's config folder, keyed by the image's absolute path. Unknown or damaged values fall back
to the defaults with a warning, never an error: losing a tweak is better than refusing to start.
"""
import hashlib
import json
import os
import sys
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

from puppet.expression import EXPRESSIONS

SETTINGS_FILE = "live.json"


@dataclass(frozen=True)
class LiveSettings:
    sensitivity_db: float = 0.0  # gain on the voice before lip sync
    gate_db: float = -50.0  # voice below this level (dBFS) counts as silence
    blink_rate: float = 15.0  # blinks per minute
    blink_randomness: float = 0.5  # spread of the gaps between blinks (0: metronome)
    idle_degrees: float = 2.0  # largest idle head turn
    expression: str = "neutral"
    push_to_talk: bool = False  # the voice only counts while Space is held
    show_stats: bool = False  # fps and latency readout in the window

    def clamped(self) -> "LiveSettings":
        """The same settings with every number inside its usable range."""
        return replace(
            self,
            sensitivity_db=min(max(self.sensitivity_db, -24.0), 24.0),
            gate_db=min(max(self.gate_db, -90.0), -10.0),
            blink_rate=min(max(self.blink_rate, 0.0), 60.0),
            blink_randomness=min(max(self.blink_randomness, 0.0), 2.0),
            idle_degrees=min(max(self.idle_degrees, 0.0), 6.0),
        )


def settings_path(puppet_path: Path | None, name: str) -> Path:
    """Where the settings of the puppet loaded from `puppet_path` live (None: the bundled demo)."""
    if puppet_path is not None and puppet_path.is_dir():
        return puppet_path / SETTINGS_FILE
    base = Path(os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config") / "puppet" / "live"
    key = str(puppet_path.resolve()) if puppet_path is not None else "demo"
    return base / f"{name}-{hashlib.sha1(key.encode()).hexdigest()[:8]}.json"


def load(path: Path) -> LiveSettings:
    """The saved settings, or the defaults when there are none (or they cannot be read)."""
    if not path.is_file():
        return LiveSettings()
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict):
            raise ValueError("not a JSON object")  # noqa: TRY004 (one handler for every bad file)
        defaults, values = LiveSettings(), {}
        for name in (f.name for f in fields(LiveSettings)):
            if name not in data:
                continue
            default, value = getattr(defaults, name), data[name]
            number = isinstance(value, (int, float)) and not isinstance(value, bool)
            if (isinstance(default, float) and not number) or (not isinstance(default, float) and type(value) is not type(default)):
                raise ValueError(f"{name} should be a {type(default).__name__}")
            values[name] = float(value) if isinstance(default, float) else value
        if values.get("expression", defaults.expression) not in EXPRESSIONS:
            raise ValueError(f"unknown expression {values['expression']!r}")
        return LiveSettings(**values).clamped()
    except ValueError as error:
        print(f"puppet: warning: ignoring {path} ({error}); using default live settings", file=sys.stderr)
        return LiveSettings()


def save(path: Path, settings: LiveSettings) -> None:
    """Write the settings (atomically; a failure to write only warns)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f".{path.name}.partial")
        partial.write_text(json.dumps(asdict(settings), indent=1))
        partial.replace(path)
    except OSError as error:
        print(f"puppet: warning: cannot save live settings to {path} ({error})", file=sys.stderr)
