"""The progress bar's keyframes and scale when the nodes run in other processes."""
import pytest

from absscale_ros import conversions, graph, params
from absscale_ros.core.errors import AbsScaleError


def _summary(*statuses: tuple[str, str, dict]) -> dict:
    msg = conversions.diagnostic_array(
        [conversions.diagnostic_status(name, 'ok', text, values)
         for name, text, values in statuses], 1_000)
    return conversions.diagnostic_summary(msg)


def test_progress_reads_keyframes_and_a_claimed_scale_from_diagnostics() -> None:
    assert graph._progress_from_diagnostics({}) == (0, None)
    selector = ('keyframe_selector: keyframes', 'selecting keyframes',
                {'frames': 120, 'keyframes': 7})
    unclaimed = ('scale: metric scale', 'no scale yet', {'observable': False})
    assert graph._progress_from_diagnostics(_summary(selector, unclaimed)) == (7, None)
    claimed = ('scale: metric scale', '0.68 m/unit', {'observable': True, 'factor': 0.68,
                                                      'sigma': 0.002, 'edges': 6})
    keyframes, scale = graph._progress_from_diagnostics(_summary(selector, claimed))
    assert keyframes == 7 and scale == (0.68, 0.002)


def test_latency_is_timed_from_each_frames_publication_and_kept_as_a_series() -> None:
    published = {10: 1_000_000_000, 20: 2_000_000_000, 30: 3_000_000_000}
    # Cloud updates stamped with frames 10 and 30 (1.5 s and 0.5 s after them); 99 unknown.
    updates = [(10, 2_500_000_000), (30, 3_500_000_000), (99, 4_000_000_000)]
    lat = graph._latency(published, updates)
    assert lat['updates'] == 2 and lat['max'] == 1.5 and lat['median'] == 1.0
    assert lat['series'] == [[0.0, 1.5], [2.0, 0.5]]  # seconds into the replay, latency
    assert graph._latency(published, []) == {'updates': 0}


def test_a_keyframe_the_live_sfm_skipped_waits_for_the_next_update_and_stages_add_up() -> None:
    published = {10: 1_000_000_000, 20: 2_000_000_000, 30: 3_000_000_000, 40: 4_000_000_000}
    # Keyframe 20 was skipped: 30's update is the first to hold the map past it. The scale
    # node republished 30 (path, new factor): only its first update counts. 40: no update.
    updates = [(10, 1_500_000_000), (30, 3_250_000_000), (30, 3_400_000_000)]
    timeline = [(10, 1_100_000_000, 1_100_000_000, 1_400_000_000),  # stamp, arrived, start, end
                (30, 3_050_000_000, 3_100_000_000, 3_200_000_000)]
    lat = graph._latency(published, updates, [10, 20, 30, 40], timeline)
    assert lat['updates'] == 2 and lat['keyframes'] == 3 and lat['never'] == 1
    assert [s for _, s in lat['series']] == [0.5, 1.25, 0.25]
    assert lat['per_update'] == {'median': 0.375, 'p95': 0.4875}
    stages = {k: v['median'] for k, v in lat['stages'].items()}
    assert stages == pytest.approx({'to_sfm': 0.075, 'waiting': 0.025, 'update': 0.2,
                                    'to_cloud': 0.075})


def test_a_step_window_wider_than_the_stamp_pairing_is_refused(tmp_path) -> None:
    """Frames in flight past pair_depth would be decided without their vertices."""
    text = params.find_config('outdoor_cube').read_text()
    assert '    step_window: 4 ' in text
    for name in params.CONFIG_NAMES:  # the shipped configs pass
        graph._check_step_window(params.load_yaml(params.find_config(name)))
    wide = tmp_path / 'wide.yaml'
    wide.write_text(text.replace('    step_window: 4 ', '    step_window: 16 '))
    with pytest.raises(AbsScaleError, match='step_window 16 > keyframe_selector pair_depth 10'):
        graph.run_graph(str(tmp_path / 'no_bag_needed.mcap'), str(wide))


def test_a_detector_on_request_beside_a_selector_that_never_asks_is_refused(tmp_path) -> None:
    """It would look at no frame: the run would claim no scale instead of failing."""
    text = params.find_config('outdoor_cube').read_text()
    detector_on = text.replace('    detect_on_request: false  # offline: look only',
                               '    detect_on_request: true  # offline: look only')
    assert detector_on != text
    alone = tmp_path / 'detector_alone.yaml'
    alone.write_text(detector_on)
    with pytest.raises(AbsScaleError, match='vertex_detector detect_on_request needs'):
        graph.run_graph(str(tmp_path / 'no_bag_needed.mcap'), str(alone))
    both = tmp_path / 'both.yaml'
    both.write_text(detector_on.replace('    detect_on_request: false',
                                        '    detect_on_request: true'))
    graph._check_step_window(params.load_yaml(both))  # the selector asks: accepted
