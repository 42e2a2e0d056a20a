"""The audio → landmark network (MakeItTalk, Zhou et al. 2020, §3.1–3.2), made causal for real time.

Sketch. Every motion step t (MOTION_FPS = 50 steps/s) reads FRAMES_PER_MOTION = 2 log-mel frames
(2 × 80 = 160 values, see puppet.features) and emits the motion of frame t − LOOKAHEAD, so the network
hears LOOKAHEAD motion frames (80 ms) of future audio and nothing beyond:

    content branch:  LSTM_c (3 layers × 256, unidirectional) → MLP_c 512/256/204 → content offsets Δq
    speaker branch:  c̃ = Linear(LSTM_c output) ⊕ MLP(speaker 256 → 128)
                     → embedding (→ d_model 32) → 2 causal self-attention layers (2 heads, window 256)
                     → MLP_s → head rotation (3) and expression offsets Δp (204)
    output:          offsets = Δq + Δp (68 × 3, soft-limited), rotation (3, soft-limited)
    exported with:   a voice detector (VoiceNet, a small GRU on the same steps) scaling the offsets
                     down where nobody speaks (GatedNetwork): music, typing and hum leave the face at rest

The paper's content window [t, t + 18] and its non-causal 256-frame attention become, here, an LSTM
that runs forward only and an attention that looks back over the last 256 steps. Both carry their
past in an explicit `State` (LSTM h/c; each attention layer's keys and values of the last 255 steps,
and which of those steps are real), so running a long input in one go or in chunks is the same computation: offline = streaming.

Differences from the paper, and why: no AutoVC content encoder (log-mels go straight in; AutoVC is
neither small nor causal); the speaker branch's c̃ is a projection of the content LSTM rather than a
second LSTM (a second 3 × 256 LSTM doubles run-time cost for little gain on small corpora); positions
in the attention are a learned linear bias per head (ALiBi; absolute positions cannot stream); MLPs
do not take the static landmarks q as input (offsets are predicted in the canonical face frame and
applied to any face by the rig).

Losses (§4.1–4.2): squared position error plus the graph-Laplacian term of Eq. 8–9 over the 8
FACIAL_PARTS, and a per-frame LSGAN discriminator (Eq. 10–12) over (landmarks + rotation, c̃, speaker).
"""
import math
from dataclasses import dataclass
from itertools import pairwise
from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from puppet.features import FRAMES_PER_MOTION, N_MELS
from puppet.landmarks import FACIAL_PARTS, INNER_LIP, N_LANDMARKS

N_INPUT = N_MELS * FRAMES_PER_MOTION  # 160 log-mel values per motion step
N_OFFSETS = N_LANDMARKS * 3  # 204
N_ROTATION = 3  # pitch, yaw, roll in radians
SPEAKER_DIM = 256  # Resemblyzer's VoiceEncoder embedding
LOOKAHEAD = 3  # motion frames of future audio: 60 ms, plus the STFT half-window (22.5 ms past a frame's end) = 82.5 ms after a frame starts, 72.5 ms after its centre


@dataclass(frozen=True)
class NetworkConfig:
    content_hidden: int = 256  # LSTM_c units per layer (paper: 256)
    content_layers: int = 3  # LSTM_c layers (paper: 3)
    dropout: float = 0.0  # between LSTM_c layers, in training only (0: none, as the shipped model)
    content_mlp: tuple[int, ...] = (512, 256)  # MLP_c hidden sizes before the 204 outputs (paper: 512, 256)
    content_code: int = 64  # c̃: the content features handed to the speaker branch
    speaker_reduced: int = 128  # the speaker embedding after its one-layer MLP (paper: 256 → 128)
    d_model: int = 32  # attention width (paper: 32)
    heads: int = 2  # attention heads (paper: 2)
    attention_layers: int = 2  # attention layers (paper: 2)
    window: int = 256  # attention window in motion steps, the current one included (paper: 256, ~5 s here)
    speaker_mlp: int = 256  # MLP_s hidden size
    lookahead: int = LOOKAHEAD  # output step t is motion frame t − lookahead
    offset_limit: float = 1.0  # |offset| stays below this (inter-ocular distances): outputs are bounded
    rotation_limit: float = 0.8  # |rotation| stays below this (radians, ~46°)
    phone_classes: int = 0  # > 0: a linear phone classifier on LSTM_c's output, for training only (not exported)


class State(NamedTuple):
    """What a stream carries from one chunk to the next (B = batch, usually 1).

    h, c: (content_layers, B, content_hidden) float32 LSTM state.
    past: (attention_layers, B, window − 1, 2 · d_model) float32 each attention layer's keys and values of the
        latest steps, oldest first.
    valid: (B, window − 1) float32, 1 where `past` holds a real step, 0 before the stream had that many.
    """

    h: torch.Tensor
    c: torch.Tensor
    past: torch.Tensor
    valid: torch.Tensor


class Output(NamedTuple):
    """One run over T steps. offsets (B, T, 68, 3) and rotation (B, T, 3) are the network's answer;
    content (B, T, 204) raw content offsets Δq, expression (B, T, 204) raw Δp, code (B, T, content_code)
    c̃, speaker (B, speaker_reduced) and phones (B, T, phone_classes) logits, or None without a phone
    classifier, are exposed for the training losses."""

    offsets: torch.Tensor
    rotation: torch.Tensor
    state: State
    content: torch.Tensor
    expression: torch.Tensor
    code: torch.Tensor
    speaker: torch.Tensor
    phones: torch.Tensor | None


def mlp(sizes: list[int]) -> nn.Sequential:
    """Linear layers of the given sizes with LeakyReLU between them (none after the last)."""
    layers = []
    for i, (n_in, n_out) in enumerate(pairwise(sizes)):
        layers.append(nn.Linear(n_in, n_out))
        if i < len(sizes) - 2:
            layers.append(nn.LeakyReLU(0.2))
    return nn.Sequential(*layers)


def soft_limit(x: torch.Tensor, limit: float) -> torch.Tensor:
    """≈ x for |x| ≪ limit, never beyond ±limit."""
    return limit * torch.tanh(x / limit)


class CausalAttention(nn.Module):
    """One Transformer encoder layer (Vaswani et al. 2017, post-norm) over a causal window.

    Step i attends to itself and the `window − 1` steps before it, those in the carried `past`
    included. Positions enter as a bias −slope_h · distance on each head's scores (ALiBi, Press et al.
    2022, with learned slopes): it streams, and is cheaper at run time than a table looked up per pair.
    """

    def __init__(self, d_model: int, heads: int, window: int):
        super().__init__()
        self.heads, self.window = heads, window
        self.query = nn.Linear(d_model, d_model)
        self.key_value = nn.Linear(d_model, 2 * d_model)
        self.out = nn.Linear(d_model, d_model)
        self.norm1, self.norm2 = nn.LayerNorm(d_model), nn.LayerNorm(d_model)
        self.feed_forward = mlp([d_model, d_model, d_model])  # paper: feed-forward as wide as its input
        # ALiBi's geometric slopes to start with: one head looks near, the other across the window.
        self.log_slope = nn.Parameter(torch.linspace(-4.0, -8.0, heads) * math.log(2.0))

    def forward(self, x: torch.Tensor, past: torch.Tensor, distance: torch.Tensor, allowed: torch.Tensor):
        """x (B, T, D); past (B, W−1, 2D) keys and values of the W−1 steps before x; distance (T, W−1+T)
        float32 steps from each query back to each key; allowed (B, 1, T, W−1+T) bool
        → y (B, T, D) and the new past (B, W−1, 2D)."""
        batch, steps, width = x.shape
        head_dim = width // self.heads
        keys_values = torch.cat([past, self.key_value(x)], dim=1)  # (B, W−1+T, 2D): only new steps are projected
        q = self.query(x).view(batch, steps, self.heads, head_dim).transpose(1, 2)  # (B, H, T, d)
        k, v = keys_values.view(batch, -1, 2, self.heads, head_dim).permute(2, 0, 3, 1, 4)  # (B, H, W−1+T, d) each
        scores = q @ k.transpose(-1, -2) / math.sqrt(head_dim) - self.log_slope.exp()[:, None, None] * distance
        attended = (scores.masked_fill(~allowed, -1e9).softmax(-1) @ v).transpose(1, 2).reshape(batch, steps, width)
        y = self.norm1(x + self.out(attended))
        y = self.norm2(y + self.feed_forward(y))
        return y, keys_values[:, -(self.window - 1) :]


class Network(nn.Module):
    """Log-mel steps + speaker embedding → landmark offsets and head rotation, one motion frame per step."""

    def __init__(self, config: NetworkConfig = NetworkConfig()):
        super().__init__()
        self.config = config
        # Per-value log-mel statistics of the training corpus, set once by training (see set_feature_stats).
        self.register_buffer("feature_mean", torch.full((N_INPUT,), -2.5))
        self.register_buffer("feature_std", torch.full((N_INPUT,), 1.5))
        self.content_lstm = nn.LSTM(N_INPUT, config.content_hidden, config.content_layers, batch_first=True, dropout=config.dropout)
        self.content_mlp = mlp([config.content_hidden, *config.content_mlp, N_OFFSETS])
        self.content_code = nn.Linear(config.content_hidden, config.content_code)
        # Not in MakeItTalk: naming the phone being spoken (an auxiliary loss in training) pushes LSTM_c
        # towards what a mouth shape depends on and away from the voice that says it.
        self.phone_head = nn.Linear(config.content_hidden, config.phone_classes) if config.phone_classes else None
        self.speaker_reduce = nn.Sequential(nn.Linear(SPEAKER_DIM, config.speaker_reduced), nn.LeakyReLU(0.2))
        self.embed = nn.Linear(config.content_code + config.speaker_reduced, config.d_model)
        self.attention = nn.ModuleList(
            CausalAttention(config.d_model, config.heads, config.window) for _ in range(config.attention_layers)
        )
        self.speaker_mlp = mlp([config.d_model, config.speaker_mlp, N_ROTATION + N_OFFSETS])
        # Start the speaker branch silent, so early training shapes the mouth through the content branch.
        nn.init.zeros_(self.speaker_mlp[-1].weight)
        nn.init.zeros_(self.speaker_mlp[-1].bias)

    def set_feature_stats(self, mean: np.ndarray, std: np.ndarray) -> None:
        """mean, std: (160,) float32 statistics of the training steps' log-mels."""
        self.feature_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.feature_std.copy_(torch.as_tensor(np.maximum(std, 1e-3), dtype=torch.float32))

    def initial_state(self, batch: int = 1) -> State:
        """The state of a stream that has heard nothing yet."""
        cfg, device = self.config, self.feature_mean.device
        zeros = torch.zeros(cfg.content_layers, batch, cfg.content_hidden, device=device)
        past = torch.zeros(cfg.attention_layers, batch, cfg.window - 1, 2 * cfg.d_model, device=device)
        return State(zeros, zeros.clone(), past, torch.zeros(batch, cfg.window - 1, device=device))

    def run(self, steps: torch.Tensor, speaker: torch.Tensor, state: State) -> Output:
        """steps (B, T, 160) float32 log10 mels (2 frames per step, see puppet.features),
        speaker (B, 256) float32 unit-norm embedding, state from `initial_state` or the previous chunk."""
        x = (steps - self.feature_mean) / self.feature_std
        hidden, (h, c) = self.content_lstm(x, (state.h, state.c))  # (B, T, 256)
        content = self.content_mlp(hidden)  # (B, T, 204)
        code = self.content_code(hidden)  # (B, T, content_code)
        speaker_code = self.speaker_reduce(speaker)  # (B, 128)
        y = self.embed(torch.cat([code, speaker_code[:, None].expand(-1, code.shape[1], -1)], dim=-1))
        # Which earlier steps each step may attend to, shared by the layers: itself and the window − 1
        # before it, among those the stream has really had.
        steps_now, keep = y.shape[1], self.config.window - 1
        distance = (torch.arange(steps_now, device=y.device) + keep)[:, None] - torch.arange(keep + steps_now, device=y.device)[None, :]  # (T, W−1+T)
        full_valid = torch.cat([state.valid, torch.ones_like(y[:, :, 0])], dim=1)  # (B, W−1+T)
        allowed = (distance >= 0) & (distance <= keep) & (full_valid[:, None, :] > 0.5)
        pasts = []
        for layer, past in zip(self.attention, state.past):
            y, new_past = layer(y, past, distance.to(y.dtype), allowed[:, None])
            pasts.append(new_past)
        valid = full_valid[:, -keep:]
        speaker_out = self.speaker_mlp(y)  # (B, T, 3 + 204)
        rotation = soft_limit(speaker_out[..., :N_ROTATION], self.config.rotation_limit)
        expression = speaker_out[..., N_ROTATION:]
        offsets = soft_limit(content + expression, self.config.offset_limit)
        offsets = offsets.view(*offsets.shape[:2], N_LANDMARKS, 3)
        phones = self.phone_head(hidden) if self.phone_head is not None else None
        return Output(offsets, rotation, State(h, c, torch.stack(pasts), valid), content, expression, code, speaker_code, phones)

    def forward(self, steps, speaker, h, c, past, valid):
        """The exported signature: flat tensors in, (offsets, rotation, h, c, past, valid) out."""
        out = self.run(steps, speaker, State(h, c, past, valid))
        return (out.offsets, out.rotation, *out.state)


class VoiceNet(nn.Module):
    """Is someone speaking? Not in MakeItTalk: the landmark network, trained on speech alone, moves the
    mouth for any loud sound (music, typing, a fan). This small causal GRU reads the same steps and is
    trained on speech against such sounds (puppet.nonspeech): output step t is the logit that motion
    frame t − lookahead is speech, so it hears exactly as far ahead as the network it gates."""

    def __init__(self, hidden: int = 64, lookahead: int = LOOKAHEAD):
        super().__init__()
        self.lookahead = lookahead
        self.register_buffer("feature_mean", torch.full((N_INPUT,), -2.5))
        self.register_buffer("feature_std", torch.full((N_INPUT,), 1.5))
        self.project = nn.Sequential(nn.Linear(N_INPUT, hidden), nn.LeakyReLU(0.2))
        self.gru = nn.GRU(hidden, hidden, batch_first=True)
        self.head = nn.Linear(hidden, 1)

    def initial_state(self, batch: int = 1) -> torch.Tensor:
        """(1, B, hidden) zeros: a stream that has heard nothing yet."""
        return torch.zeros(1, batch, self.gru.hidden_size, device=self.feature_mean.device)

    def forward(self, steps: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """steps (B, T, 160) log10 mels, h (1, B, hidden) → speech logits (B, T), h after these steps."""
        hidden, h = self.gru(self.project((steps - self.feature_mean) / self.feature_std), h)
        return self.head(hidden)[..., 0], h


VOICE_TRUST = 4.0  # the motion kept is min(1, VOICE_TRUST × p(speech)): it fades only below p = 1 / VOICE_TRUST


def voice_weight(logits: torch.Tensor) -> torch.Tensor:
    """How much of the network's motion to keep, from speech logits: min(1, VOICE_TRUST × p(speech)), so
    only a confident "nobody speaks" brings the face to rest and a voice the detector is unsure of keeps
    its mouth (real speech costs lip-sync more than a mouth moving to music: with 2 instead of 4, real
    video lip correlation fell 0.011 rather than 0.004, for a little more rest on music)."""
    return torch.clamp(VOICE_TRUST * torch.sigmoid(logits), max=1.0)


class GatedNetwork(nn.Module):
    """What is exported: the landmark network with its voice detector, the offsets scaled by voice_weight
    (head rotation untouched). The detector's GRU state rides along as one more state tensor."""

    def __init__(self, network: Network, voice: VoiceNet):
        super().__init__()
        if voice.lookahead != network.config.lookahead:
            raise ValueError(f"the voice detector hears {voice.lookahead} steps ahead, the network {network.config.lookahead}")
        self.network, self.voice = network, voice

    def forward(self, steps, speaker, h, c, past, valid, voice_h):
        """(offsets · voice_weight, rotation, h, c, past, valid, voice_h) for the flat exported inputs."""
        out = self.network.run(steps, speaker, State(h, c, past, valid))
        logits, voice_h = self.voice(steps, voice_h)
        return (out.offsets * voice_weight(logits)[..., None, None], out.rotation, *out.state, voice_h)


class Discriminator(nn.Module):
    """Attn_d of Eq. 10: per-frame realism r_t of (offsets + rotation, c̃, speaker) over a window.

    The same encoder as the generator's (2 layers, 2 heads, d_model 32; it judges whole training
    windows, so it need not be causal), then an MLP 512/256/1 (appendix A).
    """

    def __init__(self, config: NetworkConfig = NetworkConfig()):
        super().__init__()
        n_in = N_OFFSETS + N_ROTATION + config.content_code + config.speaker_reduced
        self.embed = nn.Linear(n_in, config.d_model)
        layer = nn.TransformerEncoderLayer(config.d_model, config.heads, config.d_model, dropout=0.0, batch_first=True)
        self.encoder = nn.TransformerEncoder(layer, config.attention_layers, enable_nested_tensor=False)
        self.head = mlp([config.d_model, 512, 256, 1])

    def forward(self, offsets, rotation, code, speaker):
        """offsets (B, T, 68, 3), rotation (B, T, 3), code (B, T, C), speaker (B, 128) → r (B, T)."""
        frames = torch.cat([offsets.flatten(2), rotation, code, speaker[:, None].expand(-1, code.shape[1], -1)], dim=-1)
        return self.head(self.encoder(self.embed(frames)))[..., 0]


def _part_edges(name: str, part: range) -> list[tuple[int, int]]:
    """Neighbouring landmarks along one facial part's outline (Fig. 5): eyes and lips are closed loops,
    jaw and brows open chains; the nose is its bridge, its lower rim, and the tip joined to the rim's middle."""
    points = list(part)
    if name == "nose":
        bridge, rim = points[:4], points[4:]
        return [*pairwise(bridge), *pairwise(rim), (bridge[-1], rim[len(rim) // 2])]
    edges = list(pairwise(points))
    if name.endswith(("eye", "lip")):
        edges.append((points[-1], points[0]))
    return edges


def laplacian_matrix() -> torch.Tensor:
    """(68, 68) float32 L with L @ p = the graph-Laplacian coordinates of Eq. 9: each landmark minus the
    mean of its neighbours within its facial part."""
    adjacency = np.zeros((N_LANDMARKS, N_LANDMARKS), np.float32)
    for name, part in FACIAL_PARTS.items():
        for i, j in _part_edges(name, part):
            adjacency[i, j] = adjacency[j, i] = 1.0
    degree = adjacency.sum(1, keepdims=True)
    return torch.from_numpy(np.eye(N_LANDMARKS, dtype=np.float32) - adjacency / np.maximum(degree, 1.0))


LAPLACIAN = laplacian_matrix()


def position_loss(predicted: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """First term of Eq. 8: Σ_i ‖p_i − p̂_i‖² per frame, averaged over the frames where mask (B, T) is 1.
    predicted, target: (B, T, 68, 3)."""
    per_frame = (predicted - target).square().sum((-1, -2))
    return (per_frame * mask).sum() / mask.sum().clamp(min=1.0)


def velocity_loss(predicted: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Σ_i ‖(p_i(t+1) − p_i(t)) − (p̂_i(t+1) − p̂_i(t))‖² per frame pair, averaged over pairs whose two
    frames are both masked in. predicted, target: (B, T, 68, 3); mask: (B, T). (Not in MakeItTalk: it
    aims at the paper's D-VL directly.)"""
    difference = (predicted - target).diff(dim=1)
    per_pair = difference.square().sum((-1, -2))
    pairs = mask[:, 1:] * mask[:, :-1]
    return (per_pair * pairs).sum() / pairs.sum().clamp(min=1.0)


def mouth_area(points: torch.Tensor) -> torch.Tensor:
    """(...,) area of the inner-lip polygon (60–67) of (..., 68, ≥2) points, in the x-y plane (shoelace)."""
    ring = points[..., list(INNER_LIP), :2]
    x, y = ring[..., 0], ring[..., 1]
    return 0.5 * (x * y.roll(-1, dims=-1) - x.roll(-1, dims=-1) * y).sum(-1).abs()


def mouth_area_loss(predicted: torch.Tensor, target: torch.Tensor, rest: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """|A(rest + p) − A(rest + p̂)| per frame, the inner mouth's area (IOD²), averaged over masked frames.
    predicted, target: (B, T, 68, 3) offsets from rest (68, 3); mask: (B, T). (Not in MakeItTalk: it aims
    at the paper's D-A; an absolute error, as D-A is, so that an unsure network leans to the likelier
    shape, shut or open, rather than to a half-open average.)"""
    per_frame = (mouth_area(rest + predicted) - mouth_area(rest + target)).abs()
    return (per_frame * mask).sum() / mask.sum().clamp(min=1.0)


def laplacian_loss(predicted: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Second term of Eq. 8: Σ_i ‖L(p_i) − L(p̂_i)‖² per frame (L is linear, so L(p) − L(p̂) = L(p − p̂)),
    averaged over the masked frames. predicted, target: (B, T, 68, 3); mask: (B, T)."""
    difference = torch.einsum("ij,btjk->btik", LAPLACIAN.to(predicted.device), predicted - target)
    per_frame = difference.square().sum((-1, -2))
    return (per_frame * mask).sum() / mask.sum().clamp(min=1.0)


def lsgan_losses(real: torch.Tensor, fake: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Eq. 11: Σ_t (r̂_t − 1)² + r_t², averaged over masked frames. real, fake, mask: (B, T)."""
    per_frame = (real - 1).square() + fake.square()
    return (per_frame * mask).sum() / mask.sum().clamp(min=1.0)


def lsgan_generator_loss(fake: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The adversarial term of Eq. 12: Σ_t (r_t − 1)², averaged over masked frames."""
    return ((fake - 1).square() * mask).sum() / mask.sum().clamp(min=1.0)


def phone_loss(logits: torch.Tensor, phones: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of the phone classifier, averaged over masked frames. logits (B, T, K); phones (B, T)
    int64 class of each frame; mask (B, T). (Not in MakeItTalk: an auxiliary task for LSTM_c.)"""
    per_frame = nn.functional.cross_entropy(logits.transpose(1, 2), phones, reduction="none")
    return (per_frame * mask).sum() / mask.sum().clamp(min=1.0)


def parameter_count(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
