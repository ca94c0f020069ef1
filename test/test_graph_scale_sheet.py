"""The scale node's ``sheet: auto`` follows the detector's one sheet (params.detected_sheet)."""
import numpy as np
import pytest

from absscale_ros import graph, params
from absscale_ros.core import scale, targets
from absscale_ros.core.errors import NotObservableError


def _sections(target: str, other_sheets: list[str] | None = None) -> dict:
    sections = params.load_yaml(params.find_config('indoor_paper'))
    sections['vertex_detector']['target'] = target
    if other_sheets is not None:
        sections['vertex_detector']['sheet.other_sheets'] = other_sheets
    return sections


@pytest.mark.parametrize('target, other, sheet', [
    ('letter', None, 'letter'), ('a4', None, 'a4'), ('letter', ['a4'], 'auto'),
    ('sheet', None, 'auto'), ('auto', None, 'auto'), ('cube', None, 'auto')])
def test_scale_sheet_follows_the_detector(target, other, sheet):
    sections = _sections(target, other)
    assert params.detected_sheet(sections) == sheet
    values = graph._node_values('scale', sections, ['vertex_detector', 'scale'], False)
    assert values['sheet'] == sheet


def _objects(points: np.ndarray, sheet: str) -> list[scale.ObjectVertices]:
    sizes = targets.sheet_sizes_m(sheet)
    n = len(points)
    return scale.group_objects(points, np.zeros(n, np.int64), np.zeros(n, np.int64),
                               np.full(n, 10, np.int64), np.full(n, 20.0), sizes[0], 0.8,
                               tuple(sizes[1:]))


def test_a6_card_scales_as_a4_under_auto_only():
    """An A6 card (0.105 x 0.148 m, bag 63's distractor) has A4's shape: 'auto' scales it
    as an A4 page (twice the truth), letter alone refuses it."""
    rng = np.random.default_rng(63)
    card = scale.model_vertices_m('sheet', (0.105, 0.148)) + rng.normal(0, 2e-4, (4, 3))
    est = scale.estimate(_objects(card, 'auto'), scale.ScaleConfig())
    assert est.factor == pytest.approx(2.0, rel=0.01)
    with pytest.raises(NotObservableError):
        scale.estimate(_objects(card, 'letter'), scale.ScaleConfig())
