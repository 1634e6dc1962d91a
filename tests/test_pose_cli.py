"""``scorbot-gym pose train`` and ``pose eval`` end to end on one object."""

import json

import pytest

from scorbot_gym.cli import main


@pytest.mark.slow
def test_train_then_eval(tmp_path, capsys):
    model = tmp_path / "m.npz"
    cache = str(tmp_path / "cache")
    args = ["pose", "train", "--objects", "foam_brick", "--views", "12", "--out", str(model),
            "--width", "320", "--height", "240", "--cache-dir", cache, "--quiet"]  # fmt: skip
    assert main(args) == 0
    assert model.is_file()
    out_json = tmp_path / "e.json"
    args = ["pose", "eval", "--model", str(model), "--occlusion", "0,50", "--views", "3",
            "--json", str(out_json), "--cache-dir", cache, "--quiet"]  # fmt: skip
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "occlusion 0 %" in text and "occlusion 50 %" in text and "foam_brick" in text
    data = json.loads(out_json.read_text())
    assert set(data["levels"]) == {"0", "50"}
    s = data["levels"]["0"]["all"]
    assert s["n_views"] == 3 and 0.0 <= s["success_5deg"] <= 1.0
    assert f"{s['success_5deg']:.2f}" in text  # the table shows the JSON's numbers


def test_bad_arguments_are_reported(tmp_path, capsys):
    assert main(["pose", "eval", "--model", str(tmp_path / "none.npz")]) == 2
    assert "no model file" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # names are checked while parsing
        main(["pose", "train", "--objects", "teapot", "--out", str(tmp_path / "x.npz")])
    assert exc.value.code == 2 and "unknown 'teapot'; valid:" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["pose", "eval", "--model", "m.npz", "--occlusion", "0,abc"])
    with pytest.raises(SystemExit):
        main(["pose", "train", "--jobs", "0"])
    assert "--jobs takes a positive integer, got '0'" in capsys.readouterr().err
