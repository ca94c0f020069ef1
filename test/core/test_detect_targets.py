"""The 'sheet' target: any configured page size (letter or A4), and no cube search."""
from pathlib import Path
import sys

import numpy as np

from absscale_ros.core import detect, detect_sheet

sys.path.insert(0, str(Path(__file__).parent))
import synth_targets as st  # noqa: E402


def test_sheet_target_finds_letter_and_a4_pages_and_names_each() -> None:
    cfg = detect.DetectConfig(target='sheet')
    for name, size_m in (('letter', (0.2159, 0.2794)), ('a4', (0.210, 0.297))):
        true_px = st.project_sheet((0.5, -0.3, 0.3), (0.05, 0.0, 0.9), size_m)
        img = st.render_sheet(np.random.default_rng(13), true_px)
        res = detect.detect(img, cfg, st.K)
        assert res.looked_for == ('sheet',)  # the cube detector did not run
        assert [d.name for d in res.detections] == [name]
        err = res.detections[0].vertices_px - true_px[detect_sheet._order(true_px)]
        assert np.hypot(*err.T).max() < 1.0


def test_a_letter_only_target_does_not_report_an_a4_page() -> None:
    """Why the 'sheet' target exists: a letter search refuses an A4 page (9 % off aspect)."""
    true_px = st.project_sheet((0.5, -0.3, 0.3), (0.05, 0.0, 0.9), (0.210, 0.297))
    img = st.render_sheet(np.random.default_rng(13), true_px)
    assert detect.detect(img, detect.DetectConfig(target='letter'), st.K).detections == ()
