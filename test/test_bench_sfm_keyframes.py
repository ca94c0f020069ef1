"""`bench sfm --keyframes-from`: an `absscale run`'s keyframes replayed through the core."""
import argparse
import json
from pathlib import Path

from absscale_ros.tools import bench_sfm

BAG = str(Path(__file__).parents[1] / 'bags' / 'indoor_paper_sample.mcap')


def _report(tmp_path: Path, selector: list[int], sfm: list[int] | None) -> str:
    """A report.json as `absscale run` writes it (the parts the bench reads)."""
    nodes = {'keyframe_selector': {'keyframes': len(selector), 'keyframe_stamps_ns': selector},
             'sfm': {'keyframes_in': len(sfm or []), 'keyframes_skipped': 0}}
    if sfm is not None:  # reports from before commit 8542b97 have no such list
        nodes['sfm']['keyframe_stamps_ns'] = sfm
    path = tmp_path / f'report_{sfm is not None}.json'
    path.write_text(json.dumps({'bag': BAG, 'nodes': nodes}))
    return str(path)


def test_a_live_runs_processed_keyframes_are_replayed_not_the_selectors(tmp_path, capsys) -> None:
    with open(BAG + '.gt.json') as f:
        stamps = [fr['stamp_ns'] for fr in json.load(f)['frames']]
    selector = stamps[::12]  # what the selector chose
    live = selector[:1] + selector[3::2]  # the live map skipped keyframes 1, 2, 4, 6, ...
    parser = argparse.ArgumentParser()
    bench_sfm.add_arguments(parser)
    for sfm, expected in ((live, live), (None, selector)):
        args = parser.parse_args([BAG, '--keyframes-from', _report(tmp_path, selector, sfm),
                                  '--json'])
        assert bench_sfm.run_keyframe_stamps(args.keyframes_from) == expected
        gt = {'frames': [{'stamp_ns': s} for s in stamps]}
        assert sorted(stamps[k] for k in bench_sfm._keyframe_indices(BAG, gt, args)) == expected
    # One command replays the live map's keyframes: the core gets exactly those.
    args = parser.parse_args([BAG, '--keyframes-from', _report(tmp_path, selector, live),
                              '--json'])
    assert bench_sfm.run(args) == 0
    r = json.loads(capsys.readouterr().out)
    assert len(r) == 1 and next(iter(r.values()))['keyframes_in'] == len(live)


def test_the_camera_error_is_a_share_of_the_scored_segments_own_path(tmp_path, capsys) -> None:
    with open(BAG + '.gt.json') as f:
        stamps = [fr['stamp_ns'] for fr in json.load(f)['frames']]
    parser = argparse.ArgumentParser()
    bench_sfm.add_arguments(parser)
    args = parser.parse_args([BAG, '--keyframes-from', _report(tmp_path, stamps[::6], None),
                              '--json'])
    assert bench_sfm.run(args) == 0
    fig = next(iter(json.loads(capsys.readouterr().out).values()))
    assert fig['registered'] >= 3
    # Never the whole run's path, which would flatter a map split into segments.
    assert 0.0 < fig['segment_m'] <= fig['trajectory_m'] + 1e-9
    assert fig['centre_rmse_pct'] == 100.0 * fig['centre_rmse_m'] / fig['segment_m']
    # The pose alignment fits the rotation to the orientations, so the centres fit no better
    # than Umeyama's least squares on them; the sample's path is nearly straight and the
    # centres alone swing the sheet (1 m beside the path) by about 10 mm (0.18 % of 6.6 m).
    assert fig['centre_rmse_pose_pct'] >= fig['centre_rmse_pct'] - 1e-12
    assert fig['vertices'] >= 3
    assert fig['vertex_err_median_pct'] < fig['vertex_err_median_centres_pct']
