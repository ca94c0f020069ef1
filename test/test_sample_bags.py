"""The shipped samples end to end: a true scale in its own interval (outdoor: twice the same)."""
from pathlib import Path

import cv2
import pytest

from absscale_ros import graph, params
from absscale_ros.sim import groundtruth
from absscale_ros.tools import bench_scale
from rclpy.serialization import deserialize_message

BAG = Path(__file__).resolve().parent.parent / 'bags' / 'outdoor_cube_sample.mcap'


def _run(split: bool = False) -> tuple[dict, dict]:
    report = graph.run_graph(str(BAG), 'outdoor_cube', graph.RunOptions(mode='step',
                                                                        split=split))
    latest = report.pop('_latest')
    return report, latest


@pytest.fixture(scope='module')
def one_process() -> tuple[dict, dict]:
    """The outdoor sample in one process, once for the tests below."""
    return _run()


def test_outdoor_sample_scale_is_true_and_repeatable(one_process: tuple[dict, dict]) -> None:
    first, latest = one_process
    scale = first['nodes']['scale']
    assert scale['observable'], scale
    msgs = {t: deserialize_message(d, c) for t, (c, d) in latest.items()}
    truth = bench_scale.measure(str(BAG), first, msgs, groundtruth.load(f'{BAG}.gt.json'),
                                lengths=False)
    true_factor = truth['true_factor']
    assert scale['interval'][0] <= true_factor <= scale['interval'][1], truth
    assert abs(truth['scale_error_mm_per_m']) < 10.0
    # Offline runs are deterministic: the same bag twice gives the same factor and cloud.
    second, latest2 = _run()
    assert second['nodes']['scale']['factor'] == scale['factor']
    clouds = [deserialize_message(d, c) for c, d in (latest['/scaled_cloud'],
                                                     latest2['/scaled_cloud'])]
    assert clouds[0] == clouds[1]


def test_split_run_gives_the_factor_and_cloud_of_one_process(
        one_process: tuple[dict, dict]) -> None:
    """--split (frame nodes, and the sfm, in processes of their own, one OpenCV thread each;
    scale in the runner) must not change the numbers: the random frames of test_run_end_to_end
    have no object, so only this bag checks the factor and the cloud across layouts."""
    first, latest = one_process
    threads = cv2.getNumThreads()
    split, latest_split = _run(split=True)
    assert cv2.getNumThreads() == threads  # the runner's OpenCV threads given back
    assert split['nodes']['scale']['factor'] == first['nodes']['scale']['factor']
    clouds = [deserialize_message(d, c) for c, d in (latest['/scaled_cloud'],
                                                     latest_split['/scaled_cloud'])]
    assert clouds[0] == clouds[1]


def test_scale_bench_configures_the_page_the_bag_holds(tmp_path: Path) -> None:
    """An A4 bag is benched looking for A4 (its user would configure it), a letter bag as is."""
    gt = groundtruth.load(f'{BAG}.gt.json')
    assert bench_scale._scene_config(gt, tmp_path).endswith('config/outdoor_cube.yaml')
    gt['scene'] = {'name': 'indoor_paper', 'variant': {'target': 'a4'}}
    path = bench_scale._scene_config(gt, tmp_path)
    sections = params.load_yaml(Path(path))
    assert sections['vertex_detector']['target'] == 'a4'
    assert sections['scale'] == params.load_yaml(params.find_config('indoor_paper'))['scale']


def test_indoor_sample_claims_a_true_scale() -> None:
    """The sheet path end to end: a letter page on a plain desk, 10 s of walking. And bench
    scale's Table 3 truth from the landmarks' own observations, read from the sfm's map (its
    fallback, the projected truth, would pass silently)."""
    bag = BAG.parent / 'indoor_paper_sample.mcap'
    seen: dict = {}
    report = graph.run_graph(str(bag), 'indoor_paper', graph.RunOptions(mode='step'),
                             inspect=lambda nodes: seen.update(
                                 bench_scale._cloud_observations(nodes)))
    scale = report['nodes']['scale']
    assert scale['observable'], scale
    msgs = {t: deserialize_message(d, c) for t, (c, d) in report.pop('_latest').items()}
    truth = bench_scale.measure(str(bag), report, msgs, groundtruth.load(f'{bag}.gt.json'),
                                observations=seen.get('observations'))
    assert scale['interval'][0] <= truth['true_factor'] <= scale['interval'][1], truth
    assert truth['truth'] == 'observations', truth
    # 13 landmarks published (40 without the indoor cloud's plane and incidence gates)
    assert truth['landmarks'] >= 12, truth
    assert truth['landmarks_with_truth'] >= 0.9 * truth['landmarks'], truth
