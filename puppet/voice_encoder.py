"""Export Resemblyzer's VoiceEncoder (GE2E speaker encoder, Wan et al. 2018) to ONNX.

The weights ship inside the `resemblyzer` PyPI package (`pretrained.pt`); this module rebuilds
the network (3-layer LSTM over 40 mel channels → linear 256 → ReLU → L2 norm) in torch, loads
them without importing resemblyzer itself, and writes `assets/models/voice_encoder.onnx`, which
`puppet.speaker` runs with onnxruntime. Training-time only:

    pip install resemblyzer && python -m puppet.voice_encoder
"""
import importlib.util
from importlib.resources import files
from pathlib import Path

import numpy as np
import onnxruntime
import torch
from torch import nn

from puppet.speaker import EMBEDDING_SIZE, MEL_CHANNELS, MODEL_FILE

HIDDEN = 256
LAYERS = 3


class VoiceEncoder(nn.Module):
    def __init__(self):
        super().__init__()
        self.lstm = nn.LSTM(MEL_CHANNELS, HIDDEN, LAYERS, batch_first=True)
        self.linear = nn.Linear(HIDDEN, EMBEDDING_SIZE)

    def forward(self, mels: torch.Tensor) -> torch.Tensor:
        """(B, F, 40) power mels → (B, 256) unit-norm embeddings."""
        _, (hidden, _) = self.lstm(mels)
        raw = torch.relu(self.linear(hidden[-1]))
        return raw / torch.linalg.vector_norm(raw, dim=1, keepdim=True).clamp_min(1e-12)


def resemblyzer_weights() -> Path:
    spec = importlib.util.find_spec("resemblyzer")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("pip install resemblyzer: its package carries the voice encoder's weights")
    return Path(spec.submodule_search_locations[0]) / "pretrained.pt"


def export(out: Path) -> None:
    model = VoiceEncoder()
    state = torch.load(resemblyzer_weights(), map_location="cpu", weights_only=True)["model_state"]
    model.load_state_dict({k: v for k, v in state.items() if k.startswith(("lstm.", "linear."))})
    model.eval()
    example = torch.rand(2, 160, MEL_CHANNELS)
    torch.onnx.export(
        model, (example,), str(out), input_names=["mels"], output_names=["embeddings"],
        dynamic_axes={"mels": {0: "batch", 1: "frames"}, "embeddings": {0: "batch"}}, opset_version=17, dynamo=False,
    )
    check = torch.rand(3, 160, MEL_CHANNELS) * 5
    session = onnxruntime.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    (onnx_out,) = session.run(None, {"mels": check.numpy()})
    with torch.no_grad():
        torch_out = model(check).numpy()
    assert np.abs(onnx_out - torch_out).max() < 1e-4, np.abs(onnx_out - torch_out).max()
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB); onnxruntime matches torch")


if __name__ == "__main__":
    export(Path(str(files("puppet.assets") / "models" / MODEL_FILE)))
