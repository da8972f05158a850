"""A node's part of the site's configuration: every mistake is exit 2 naming the file."""

from __future__ import annotations

import pytest

from stereopose.cli import main
from stereopose.errors import ConfigError
from stereopose.nodes.node import plan_node
from stereopose.site.plan import plan_serve


@pytest.fixture
def config(tmp_path):
    from stereopose.pipeline.demo import write_serve_demo_config

    path = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", 0)
    text = path.read_text().replace("[serve]\n", '[mqtt]\nhost = "127.0.0.1"\n\n[serve]\n', 1)
    text += '[[nodes]]\nname = "node-a"\ncameras = ["cam01", "cam02"]\n'
    path.write_text(text)
    return path


def test_a_node_takes_its_cameras_from_its_entry_or_the_command_line(config):
    plan = plan_node(config, node="node-a")
    assert (plan.name, plan.rig.names) == ("node-a", ("cam01", "cam02"))
    assert plan.rig["cam01"].size == (1088, 1920)
    plan = plan_node(config, ["cam04", "cam03"], name="edge-2")
    assert (plan.name, plan.rig.names) == ("edge-2", ("cam04", "cam03"))
    assert plan.loop == (True, True)


@pytest.mark.parametrize(
    ("args", "why"),
    [
        ({}, "needs its cameras"),
        ({"cameras": ["cam09"]}, "cam09 not among its"),
        ({"cameras": ["cam01", "cam01"]}, "named twice"),
        ({"node": "node-z"}, "no \\[\\[nodes\\]\\] entry named 'node-z'"),
        ({"node": "node-a", "cameras": ["cam03"]}, "not both"),
    ],
)
def test_a_wrong_node_is_named(config, args, why):
    with pytest.raises(ConfigError, match=why):
        plan_node(config, **args)


def test_a_node_needs_the_sites_broker_and_so_does_a_service_fed_by_nodes(config, capsys):
    text = config.read_text().replace('[mqtt]\nhost = "127.0.0.1"\n', "")
    config.write_text(text)
    with pytest.raises(ConfigError, match=r"mqtt\.host"):
        plan_node(config, ["cam01"])
    config.write_text(text.replace("[serve]\n", '[input]\ndetection = "nodes"\n\n[serve]\n'))
    with pytest.raises(ConfigError, match=r'detection = "nodes".*set \[mqtt\] host'):
        plan_serve(config)
    assert main(["detect-node", str(config), "--cameras", "cam01"]) == 2
    err = capsys.readouterr().err
    assert str(config.name) in err and "Traceback" not in err
