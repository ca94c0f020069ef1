"""
CPU time per frame of the vertex detector against a baseline tree, interleaved frame by frame
(one OpenCV thread), so both see the same load: the ratio is the figure.

  python test/bench/detect_cpu.py --base /tmp/base_tree /tmp/d5/*.mcap

The baseline's ``absscale_ros`` is copied under another package name (its absolute imports
renamed) so both detectors live in one process. Frames go through each tree's detector in
order, as in its vertex_detector node (with its ``cube_track.CubeTracker`` and
``sheet_track.SheetHistory`` where it has them).
Accuracy is `absscale bench detect`'s job.
"""
import argparse
import importlib
import json
from pathlib import Path
import shutil
import sys
import tempfile
import time
from typing import Iterator

from absscale_ros import bagio, conversions
from absscale_ros.core import detect as new
import cv2
import numpy as np


def load_base(tree: Path, into: Path) -> object:
    """``core.detect`` of the package in ``tree``, imported as ``absscale_base``."""
    shutil.copytree(tree / 'absscale_ros', into / 'absscale_base')
    for py in (into / 'absscale_base').rglob('*.py'):
        py.write_text(py.read_text().replace('absscale_ros', 'absscale_base'))
    sys.path.insert(0, str(into))
    return importlib.import_module('absscale_base.core.detect')


def _tracker(mod: object, target: str) -> object | None:
    """A cube tracker of the tree of ``mod`` (its ``core.detect``) for ``target``, or None."""
    track = getattr(mod, 'cube_track', None)
    if track is None or target not in ('cube', 'auto'):
        return None
    return track.CubeTracker(mod.DetectConfig(target=target).cube)


def _history(mod: object, target: str) -> object | None:
    """A sheet aspect history of the tree of ``mod`` (its ``core.detect``) for ``target``, or
    None (no sheet looked for, or a tree without ``sheet_track``)."""
    track = getattr(mod, 'sheet_track', None)
    return None if track is None or target == 'cube' else track.SheetHistory()


def bag_sheet(path: str) -> tuple[dict, np.ndarray, str]:
    """The ground truth of a simulator bag, its K and its sheet name (letter on a cube bag)."""
    gt = json.loads(Path(path + '.gt.json').read_text())
    sheet = gt['scene']['variant']['target']
    return gt, np.array(gt['camera']['K'], float), 'letter' if sheet == 'cube' else sheet


def bag_frames(path: str, gt: dict) -> Iterator[np.ndarray]:
    """The frames of a simulator bag, in order, as BGR images."""
    with bagio.open_bag(path) as reader:
        for raw in reader.messages([gt['bag']['image_topic']]):
            msg = reader.deserialize(raw)
            yield conversions.compressed_msg_to_bgr(msg) \
                if raw.msgtype.endswith('CompressedImage') else conversions.image_msg_to_bgr(msg)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bags', nargs='+', help='simulator bags (BAG.gt.json beside each)')
    parser.add_argument('--base', required=True, type=Path, help='baseline source tree')
    parser.add_argument('--targets', nargs='+', default=['sheet', 'cube', 'auto'],
                        choices=['sheet', 'cube', 'auto'], help="('sheet': the bag's own)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    times: dict[tuple[str, str], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        old = load_base(args.base, Path(tmp))
        for path in args.bags:
            gt, K, sheet = bag_sheet(path)
            kinds = [sheet if t == 'sheet' else t for t in args.targets]
            trackers = {(name, target): _tracker(mod, target) for name, mod in
                        (('base', old), ('new', new)) for target in kinds}
            histories = {(name, target): _history(mod, target) for name, mod in
                         (('base', old), ('new', new)) for target in kinds}
            for k, img in enumerate(bag_frames(path, gt)):
                order = (('base', old), ('new', new))
                for target in kinds:
                    for name, mod in order if k % 2 else order[::-1]:
                        cfg = mod.DetectConfig(target=target)
                        # (only what the tree has: a base tree may lack either)
                        kwargs = {key: state for key, state in (
                            ('tracker', trackers[(name, target)]),
                            ('sheet_history', histories[(name, target)]))
                            if state is not None}
                        t0 = time.process_time()
                        mod.detect(img, cfg, K, **kwargs)
                        kind = target if target in ('cube', 'auto') else 'sheet'
                        times.setdefault((name, kind), []).append(
                            1e3 * (time.process_time() - t0))
    for kind in args.targets:
        b, n = np.array(times[('base', kind)]), np.array(times[('new', kind)])
        bm, bp, nm, np95 = np.median(b), np.percentile(b, 95), np.median(n), np.percentile(n, 95)
        print(f'{kind:6s} base median {bm:6.2f} p95 {bp:6.2f} ms | new median {nm:6.2f} '
              f'p95 {np95:6.2f} ms | ratio {nm / bm:.2f} / {np95 / bp:.2f} (n={len(b)})')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
