"""`stereopose init --serve`: the example service configuration, loadable by the schema."""

from __future__ import annotations

from importlib import resources

from stereopose.cli import main
from stereopose.config import load_config


def test_init_serve_writes_the_example_service_configuration(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "--serve"]) == 0
    path = tmp_path / "stereopose-serve.toml"
    example = resources.files("stereopose") / "data" / "example_serve.toml"
    assert path.read_text("utf-8") == example.read_text("utf-8")
    assert load_config(path).serve.port == 8787
    assert main(["init", "--serve"]) == 2  # never written over without --force
    assert main(["init", "--serve", "--force"]) == 0
    assert main(["init", str(tmp_path / "run.toml")]) == 0
    assert "[serve]" not in (tmp_path / "run.toml").read_text("utf-8")
