import pytest

torch = pytest.importorskip("torch")

from puppet.network import (
    LAPLACIAN,
    Discriminator,
    GatedNetwork,
    Network,
    NetworkConfig,
    VoiceNet,
    laplacian_loss,
    lsgan_losses,
    mouth_area,
    mouth_area_loss,
    position_loss,
    velocity_loss,
    voice_weight,
)

SMALL = NetworkConfig(content_hidden=32, content_mlp=(64, 32), content_code=16, speaker_reduced=16, window=16, speaker_mlp=32)


def make(config=None, seed=0):
    torch.manual_seed(seed)
    net = Network(config or NetworkConfig()).eval()
    torch.nn.init.normal_(net.speaker_mlp[-1].weight, std=0.1)  # wake the zero-initialised speaker branch
    return net


def inputs(steps, seed=1):
    g = torch.Generator().manual_seed(seed)
    audio = torch.randn(1, steps, 160, generator=g) * 1.5 - 2.5
    speaker = torch.nn.functional.normalize(torch.randn(1, 256, generator=g), dim=-1)
    return audio, speaker


def test_shapes_and_bounds():
    net = make()
    audio, speaker = inputs(40)
    with torch.no_grad():
        out = net.run(audio, speaker, net.initial_state())
    assert out.offsets.shape == (1, 40, 68, 3) and out.rotation.shape == (1, 40, 3)
    assert out.state.h.shape == (3, 1, 256) and out.state.past.shape == (2, 1, 255, 64)
    assert out.offsets.abs().max() < net.config.offset_limit and out.rotation.abs().max() < net.config.rotation_limit
    assert 1_000_000 < sum(p.numel() for p in net.parameters()) < 7_500_000  # ≤ 30 MB as float32


def test_causal_with_lookahead():
    """Output step t (motion frame t − lookahead) never depends on audio after step t."""
    net = make(SMALL)
    audio, speaker = inputs(60)
    changed = audio.clone()
    changed[:, 30:] = torch.randn(1, 30, 160) * 3
    with torch.no_grad():
        a = net.run(audio, speaker, net.initial_state()).offsets
        b = net.run(changed, speaker, net.initial_state()).offsets
    assert torch.equal(a[:, :30], b[:, :30])
    assert not torch.allclose(a[:, 30:], b[:, 30:])


def test_chunks_equal_one_run():
    """The window is longer than the chunks and shorter than the input: state carries all that matters."""
    net = make(SMALL)
    audio, speaker = inputs(70)
    with torch.no_grad():
        whole = net.run(audio, speaker, net.initial_state())
        state, parts = net.initial_state(), []
        for start, stop in [(0, 1), (1, 9), (9, 10), (10, 41), (41, 70)]:
            out = net.run(audio[:, start:stop], speaker, state)
            state = out.state
            parts.append(out.offsets)
    torch.testing.assert_close(torch.cat(parts, 1), whole.offsets, atol=1e-5, rtol=0)


def test_attention_window_forgets():
    """Steps further back than the window reach the output only through the LSTM state."""
    config = NetworkConfig(content_hidden=32, content_mlp=(64, 32), content_code=16, speaker_reduced=16, window=8, speaker_mlp=32)
    net = make(config)
    audio, speaker = inputs(30)
    with torch.no_grad():
        out = net.run(audio, speaker, net.initial_state())
    assert out.state.valid.sum() == 7


def test_laplacian_loss():
    mask = torch.ones(2, 5)
    target = torch.randn(2, 5, 68, 3)
    assert laplacian_loss(target, target, mask) == 0
    assert laplacian_loss(target + torch.tensor([0.3, -0.2, 0.1]), target, mask) < 1e-9  # a translation keeps the shape
    moved = target.clone()
    moved[:, :, 62, 1] += 0.1  # one inner-lip point
    assert laplacian_loss(moved, target, mask) > 0
    assert position_loss(moved, target, mask) == pytest.approx(0.01, rel=1e-4)
    assert torch.allclose(LAPLACIAN.sum(1), torch.zeros(68), atol=1e-6)  # rows: point minus mean of neighbours


def test_velocity_loss():
    """Zero for a shifted copy (same velocities); positive for a jittered one; masked frames don't count."""
    mask = torch.ones(1, 6)
    target = torch.randn(1, 6, 68, 3)
    assert velocity_loss(target + 0.5, target, mask) < 1e-9
    jitter = target.clone()
    jitter[:, 3, 62, 1] += 0.1  # one frame of one inner-lip point: two velocities off by 0.1
    assert velocity_loss(jitter, target, mask) == pytest.approx(2 * 0.01 / 5, rel=1e-4)
    mask[:, 3] = 0  # both pairs touching frame 3 drop out
    assert velocity_loss(jitter, target, mask) < 1e-9


def test_mouth_area_loss():
    """The inner-lip polygon's area, as evaluate.mouth_area measures it; its loss is the mean absolute
    area error over masked frames and ignores motion that keeps the area (a shift, other landmarks)."""
    import numpy as np

    from puppet import evaluate
    from puppet.visemes import canonical_rest

    rest = torch.from_numpy(canonical_rest())
    g = torch.Generator().manual_seed(3)
    target = 0.05 * torch.randn(1, 4, 68, 3, generator=g)
    assert np.allclose(mouth_area(rest + target)[0].numpy(), evaluate.mouth_area((rest + target)[0].numpy()), atol=1e-7)
    mask = torch.ones(1, 4)
    assert mouth_area_loss(target + torch.tensor([0.2, -0.1, 0.3]), target, rest, mask) < 1e-6
    brows = target.clone()
    brows[:, :, 17:27] += 0.1
    assert mouth_area_loss(brows, target, rest, mask) == 0
    opened = target.clone()
    opened[:, 2, 65:68, 1] += 0.1  # frame 2: the lower inner lip drops
    gain = float(mouth_area(rest + opened)[0, 2] - mouth_area(rest + target)[0, 2])
    assert gain > 0
    assert float(mouth_area_loss(opened, target, rest, mask)) == pytest.approx(gain / 4, rel=1e-5)
    mask[:, 2] = 0
    assert mouth_area_loss(opened, target, rest, mask) == 0


def test_discriminator_and_lsgan():
    config = NetworkConfig()
    disc = Discriminator(config)
    r = disc(torch.zeros(2, 10, 68, 3), torch.zeros(2, 10, 3), torch.zeros(2, 10, config.content_code), torch.zeros(2, config.speaker_reduced))
    assert r.shape == (2, 10)
    ones, zeros, mask = torch.ones(2, 10), torch.zeros(2, 10), torch.ones(2, 10)
    assert lsgan_losses(ones, zeros, mask) == 0 and lsgan_losses(zeros, ones, mask) == 2


def test_the_voice_detector_streams_and_is_causal_with_its_lookahead():
    torch.manual_seed(0)
    voice = VoiceNet(hidden=16, lookahead=3).eval()
    audio, _ = inputs(40)
    with torch.no_grad():
        whole, _ = voice(audio, voice.initial_state())
        first, h = voice(audio[:, :17], voice.initial_state())
        rest, _ = voice(audio[:, 17:], h)
        changed = audio.clone()
        changed[:, 30:] += 1.0
        later, _ = voice(changed, voice.initial_state())
    torch.testing.assert_close(torch.cat([first, rest], 1), whole, atol=1e-6, rtol=0)
    torch.testing.assert_close(later[:, :30], whole[:, :30])  # output step t hears steps ≤ t only
    assert (later[:, 30:] != whole[:, 30:]).all()


def test_only_a_confident_no_voice_stills_the_face():
    weight = voice_weight(torch.tensor([-8.0, -2.0, -1.0, 0.0, 3.0]))  # p(speech) 0.0003, 0.12, 0.27, 0.5, 0.95
    assert weight[0] < 0.002 and 0.45 < weight[1] < 0.5 and (weight[2:] == 1).all()


def test_a_gate_must_hear_as_far_ahead_as_its_network():
    with pytest.raises(ValueError, match="ahead"):
        GatedNetwork(Network(SMALL), VoiceNet(hidden=8, lookahead=SMALL.lookahead + 1))
