import json

from puppet.bench import main


def test_bench_reports_every_figure(capsys):
    assert main(as_json=True, seconds=0.2, clip_seconds=2.0) == 0
    figures = json.loads(capsys.readouterr().out)
    for key in ["render_fps_512", "floor_fps_512", "render_fps_1080", "floor_fps_1080", "export_realtime_x_512"]:
        assert figures[key] > 0, key
    assert 0 < figures["live_fps"] <= 66 and 0 < figures["live_latency_ms_p50"] <= figures["live_latency_ms_p95"]
    from puppet import lipsync

    if lipsync.has_model():
        for key in ["predictor_ms_per_frame", "predict_realtime_x", "recognise_realtime_x"]:
            assert figures[key] > 0, key
