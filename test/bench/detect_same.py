"""
Whether a tree's detector gives the same detections as a baseline tree's, frame by frame.

  python test/bench/detect_same.py --base /tmp/base_tree BAG... [--targets sheet cube auto]

Each bag's frames go through both trees' detectors in order, as ``detect_cpu.py`` feeds them
(the same trackers and histories, intrinsics from BAG.gt.json), for the bag's sheet
('sheet': the sheet of its ground truth, letter on a cube bag), the cube and auto. Prints
per bag and target the frames compared and those that differ (vertices, ids, names, scores or
outlines; ``--tol`` px on coordinates and scores, 0: bit for bit), with the first
differences, and how many frames differ by at most ``--tol`` (the largest difference: inf when
detections, names, ids or outline sizes differ).
"""
import argparse
import importlib.util
from pathlib import Path
import sys
import tempfile

from absscale_ros.core import detect as new
import cv2
import numpy as np

_spec = importlib.util.spec_from_file_location('detect_cpu', Path(__file__).with_name(
    'detect_cpu.py'))
detect_cpu = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(detect_cpu)


def summary(result: object) -> list[tuple]:
    """Every field of a frame's detections that a consumer sees, as plain tuples."""
    return [(d.target_type, d.name, round(float(d.score), 12),
             np.asarray(d.vertices_px, float), tuple(int(i) for i in d.vertex_ids),
             tuple(tuple(int(v) for v in e) for e in d.edges),
             tuple((label, np.asarray(p, float)) for label, p in d.polygons),
             None if d.vertex_scores is None else np.asarray(d.vertex_scores, float))
            for d in result.detections]


def gap(a: list[tuple], b: list[tuple]) -> float:
    """The largest difference between two ``summary`` lists in px (or score), inf when they
    differ in anything else (detections, kinds, names, ids, edges, outline sizes)."""
    if len(a) != len(b):
        return np.inf
    worst = 0.0
    for x, y in zip(a, b):
        if x[:2] != y[:2] or x[4:6] != y[4:6] or x[3].shape != y[3].shape or \
                len(x[6]) != len(y[6]) or (x[7] is None) != (y[7] is None):
            return np.inf
        pairs = [(x[3], y[3]), (np.array([x[2]]), np.array([y[2]]))] + \
            [(pa, pb) for (_, pa), (_, pb) in zip(x[6], y[6])] + \
            ([] if x[7] is None else [(x[7], y[7])])
        if any(pa.shape != pb.shape for pa, pb in pairs) or \
                any(la != lb for (la, _), (lb, _) in zip(x[6], y[6])):
            return np.inf
        worst = max([worst] + [float(np.abs(pa - pb).max(initial=0.0)) for pa, pb in pairs])
    return worst


def brief(s: list[tuple]) -> str:
    """One line per detection: kind, name and corners rounded to 0.01 px."""
    return '; '.join(f'{t[0]} {t[1]} {np.round(t[3], 2).tolist()}' for t in s) or 'nothing'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bags', nargs='+', help='simulator bags (BAG.gt.json beside each)')
    parser.add_argument('--base', required=True, type=Path, help='baseline source tree')
    parser.add_argument('--targets', nargs='+', default=['sheet', 'cube', 'auto'])
    parser.add_argument('--tol', type=float, default=0.0)
    parser.add_argument('--show', type=int, default=5, help='differences printed per bag')
    args = parser.parse_args()
    cv2.setNumThreads(1)
    differ = 0
    with tempfile.TemporaryDirectory() as tmp:
        old = detect_cpu.load_base(args.base, Path(tmp))
        for path in args.bags:
            gt, K, sheet = detect_cpu.bag_sheet(path)
            names = [sheet if t == 'sheet' else t for t in args.targets]
            state = {(mod.__name__, t): {key: s for key, s in (
                ('tracker', detect_cpu._tracker(mod, t)),
                ('sheet_history', detect_cpu._history(mod, t))) if s is not None}
                for mod in (old, new) for t in names}
            diffs: dict[str, list[str]] = {t: [] for t in names}
            within = {t: 0 for t in names}  # frames that differ by at most ``--tol``
            worst = {t: 0.0 for t in names}
            worst_within = {t: 0.0 for t in names}
            n = 0
            for k, img in enumerate(detect_cpu.bag_frames(path, gt)):
                n += 1
                for t in names:
                    a, b = (summary(mod.detect(img, mod.DetectConfig(target=t), K,
                                               **state[(mod.__name__, t)]))
                            for mod in (old, new))
                    d = gap(a, b)
                    if d > args.tol:
                        worst[t] = max(worst[t], d)
                        diffs[t].append(f'  frame {k} (gap {d:.3g}): base {brief(a)}\n'
                                        f'  {" " * len(str(k))}        new  {brief(b)}')
                    elif d > 0.0:
                        within[t] += 1
                        worst_within[t] = max(worst_within[t], d)
            for t in names:
                print(f'{Path(path).name} {t}: {n} frames, {len(diffs[t])} differ by more than '
                      f'{args.tol:g} (largest {worst[t]:.3g}), {within[t]} within it '
                      f'(largest {worst_within[t]:.3g})')
                for line in diffs[t][:args.show]:
                    print(line)
                differ += len(diffs[t])
            sys.stdout.flush()
    print('identical' if differ == 0 else f'{differ} frame detections differ')
    return 0 if differ == 0 else 1


if __name__ == '__main__':
    raise SystemExit(main())
