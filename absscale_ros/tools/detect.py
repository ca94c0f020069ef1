"""``absscale detect IMAGE... --target letter|a4|cube|auto [--json]``: vertices in image files."""
import argparse
import json
import time

import cv2

from absscale_ros.core import detect, errors


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('images', nargs='+', metavar='IMAGE', help='image files (any cv2 format)')
    parser.add_argument('--target', default='auto', choices=detect.TARGET_CHOICES,
                        help="what to look for (default: auto = letter sheet and cube)")
    parser.add_argument('--size-m', type=float, nargs=2, metavar=('SHORT', 'LONG'),
                        help='sheet size for --target custom, m')
    parser.add_argument('--json', action='store_true', help='one JSON object per image and line')


def run(args: argparse.Namespace) -> int:
    # Still images have no frame budget: the straight-edge sheet hypotheses are on.
    sheet = detect.detect_sheet.SheetConfig(sheet='custom', size_m=tuple(args.size_m),
                                            line_candidates=True) \
        if args.size_m else detect.detect_sheet.SheetConfig(line_candidates=True)
    cfg = detect.DetectConfig(target=args.target, sheet=sheet)
    for path in args.images:
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        if image is None:
            raise errors.AbsScaleError(f'cannot read image {path!r}')
        t0 = time.perf_counter()
        result = detect.detect(image, cfg)
        ms = 1e3 * (time.perf_counter() - t0)
        objs = [detect.detection_to_dict(d) for d in result.detections]
        if args.json:
            print(json.dumps({'image': path, 'width': image.shape[1], 'height': image.shape[0],
                              'target': args.target, 'time_ms': round(ms, 2),
                              'targets': objs}))
            continue
        print(f'{path}: {len(objs)} target(s) in {ms:.1f} ms')
        for o in objs:
            print(f'  object {o["object_id"]} {o["target_type"]} ({o["name"]}) '
                  f'score {o["score"]:.2f}')
            for v in o['vertices']:  # type: ignore[attr-defined]
                print(f'    id {v["id"]:>3}  u {v["u_px"]:9.2f}  v {v["v_px"]:9.2f}')
    return 0
