"""Every parameter a node declares is listed, with a comment, in every shipped config.

The nodes declare their parameters from the core's config dataclasses, so a new field is a new
parameter; a config file that does not list it hides it from users (session 16's review found 18
such). Nodes are built as the runner builds them, with no parameter file.
"""
import importlib
from pathlib import Path
import re

from absscale_ros import graph, params
from absscale_ros.nodes.bag_replay import BagReplayNode
import pytest
import rclpy
from rclpy.parameter import Parameter

SAMPLE_BAG = Path(__file__).resolve().parents[1] / 'bags' / 'indoor_paper_sample.mcap'
# Declared by rclpy for every node, not by us.
ROS_OWN = {'use_sim_time', 'start_type_description_service'}
# An empty list has no type in a parameter file, so this one is listed as a comment.
LISTED_AS_COMMENT = {'vertex_detector': {'sheet.other_sheets'}}
# Per run, not per scene: `absscale run` and the launch file set them.
PER_RUN = {'bag_replay': {'bag', 'expect_nodes'}}


def _declared(context) -> dict[str, set[str]]:
    nodes = [('bag_replay', BagReplayNode(context=context, parameter_overrides=[
        Parameter('bag', value=str(SAMPLE_BAG))]))]
    nodes += [(name, getattr(importlib.import_module(module), cls)(context=context))
              for name, module, cls in graph.PIPELINE]
    declared = {name: set(node._parameters) - ROS_OWN for name, node in nodes}
    for _, node in nodes:
        node.destroy_node()
    return declared


@pytest.fixture(scope='module')
def declared():
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield _declared(context)
    finally:
        rclpy.shutdown(context=context)


@pytest.mark.parametrize('config', params.CONFIG_NAMES)
def test_every_declared_parameter_is_in_the_config(declared, config: str) -> None:
    path = params.find_config(config)
    sections = params.load_yaml(path)
    text = path.read_text()
    for node, names in declared.items():
        listed = set(params.node_params(sections, node))
        missing = names - listed - LISTED_AS_COMMENT.get(node, set()) - PER_RUN.get(node, set())
        assert not missing, f'{path.name}: {node} does not list {sorted(missing)}'
        assert not listed - names, f'{path.name}: {node} lists unknown {sorted(listed - names)}'
        for name in LISTED_AS_COMMENT.get(node, set()):
            assert re.search(rf'#\s*{name.split(".")[-1]}:', text), name


@pytest.mark.parametrize('config', params.CONFIG_NAMES)
def test_every_parameter_line_has_a_comment(config: str) -> None:
    path = params.find_config(config)
    bare = [line for line in path.read_text().splitlines()
            if re.match(r'\s*[A-Za-z_]\w*:\s*\S', line) and '#' not in line]
    assert not bare, f'{path.name}: parameters without a comment: {bare[:3]}'
