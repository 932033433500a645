import numpy as np

from manualcontrol.bench import demo
from manualcontrol.envs.recording import Recording


def test_demo_writes_a_loadable_recording_and_a_png(tmp_path, capsys):
    assert demo.main(["--out", str(tmp_path)]) == 0
    recording = Recording.load(tmp_path / "preview_run.npz")
    assert recording.duration == 120.0
    assert abs(recording.metadata["remnant_power_ratio"] - 0.35) < 0.05 * 0.35
    # the closed loop tracks: error smaller than the target it follows, e = ft - y
    assert np.std(recording.e) < np.std(recording.ft)
    np.testing.assert_allclose(recording.e, recording.ft - recording.y, atol=1e-12)
    png = (tmp_path / "preview_run.png").read_bytes()
    assert png.startswith(b"\x89PNG")
    assert "figure:" in capsys.readouterr().out
    assert not list(tmp_path.glob(".*part*"))  # no temporary debris
