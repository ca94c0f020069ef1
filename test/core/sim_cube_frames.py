"""Rendered cube frames under test/data (a folder with frames.json): load, detect, score."""
import json
from pathlib import Path

import cv2
import numpy as np

from absscale_ros.core import detect_cube

DATA = Path(__file__).parents[1] / 'data'


def frames(folder: str) -> dict:
    """Return file name -> its frames.json entry, for ``test/data/<folder>``."""
    listed = json.loads((DATA / folder / 'frames.json').read_text())['frames']
    return {f['file']: f for f in listed}


def cubes(folder: str, name: str, **kw):
    """Return (frames.json entry, ``detect_cubes`` with the given config fields and its K)."""
    fr = frames(folder)[name]
    img = cv2.imread(str(DATA / folder / name))
    return fr, detect_cube.detect_cubes(img, detect_cube.CubeConfig(**kw), np.array(fr['K']))


def errors(fr, det):
    """Per detected vertex: (px to the nearest true visible vertex, that vertex's edge px)."""
    true = np.array([v if v is not None and vis else [np.nan, np.nan]
                     for v, vis in zip(fr['vertices_px'], fr['vertex_visible'])], float)
    out = []
    for p in det.vertices_px:
        d = np.hypot(*(true - p).T)
        i = int(np.nanargmin(d))
        nbrs = [b if a == i else a for a, b in fr['edges'] if i in (a, b)]
        edge = max(np.hypot(*(np.array(fr['vertices_px'][j]) - true[i]))
                   for j in nbrs if fr['vertices_px'][j] is not None)
        out.append((d[i], edge))
    return np.array(out)
