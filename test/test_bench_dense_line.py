"""`bench dense` prints completeness per depth fifth, where an outdoor shortfall lies."""
from absscale_ros.tools import bench_dense

FIGURES = {'bag': 'b.mcap', 'points': 9000, 'sparse_ratio': 300.0, 'keyframes': 12,
           'median_scene_depth_m': 6.0, 'median_rel': 0.0013, 'p90_rel': 0.006,
           'distance_median_m': 0.008, 'distance_p90_m': 0.036, 'completeness': 0.64,
           'surface_samples': 20000, 'radius_m': 0.05, 'update_s_median': 1.5,
           'update_s_p95': 2.1}


def test_the_line_names_each_depth_fifth_when_the_evaluation_gave_them() -> None:
    line = bench_dense._line({**FIGURES,
                              'completeness_by_depth': [0.988, 0.914, 0.892, 0.43, 0.004]})
    assert 'completeness 64.0 % of 20000 samples within 5 cm (by depth fifth ' \
        '99 / 91 / 89 / 43 / 0 %)' in line


def test_a_result_without_fifths_prints_as_before() -> None:
    line = bench_dense._line(FIGURES)
    assert 'within 5 cm; update CPU median 1.50 s (p95 2.10)' in line


def test_the_line_gives_the_update_wall_time_beside_its_cpu() -> None:
    line = bench_dense._line({**FIGURES, 'update_wall_s_median': 1.25,
                              'update_wall_s_p95': 3.5})
    assert 'update CPU median 1.50 s (p95 2.10), wall 1.25 s (p95 3.50)' in line
