"""``absscale calibrate VIDEO --board 9x6 --square 0.025``: a ROS calibration YAML from a video."""
import argparse
from pathlib import Path

from absscale_ros.core import calibration
from absscale_ros.core.errors import AbsScaleError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('video', help='video file (or device index) showing a chessboard')
    parser.add_argument('--board', default='9x6', help='inner corners, COLSxROWS')
    parser.add_argument('--square', type=float, default=0.025, help='square side, m')
    parser.add_argument('--out', default='camera.yaml', help='calibration YAML to write')
    parser.add_argument('--every', type=int, default=5, help='look at every Nth frame')
    parser.add_argument('--name', default='camera', help='camera_name in the YAML')


def run(args: argparse.Namespace) -> int:
    import cv2
    cols, rows = (int(v) for v in args.board.lower().split('x'))
    cfg = calibration.CalibrationConfig((cols, rows), args.square)
    source = int(args.video) if args.video.isdigit() else args.video
    if isinstance(source, str) and not Path(source).exists():
        raise AbsScaleError(f'{source}: no such video file')
    cap = cv2.VideoCapture(source)
    if not cap.isOpened():
        raise AbsScaleError(f'{args.video}: cannot open as a video')
    corners, size, index = [], None, 0
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        index += 1
        if (index - 1) % args.every:
            continue
        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        size = (gray.shape[1], gray.shape[0])
        found = calibration.find_board(gray, cfg)
        if found is not None:
            corners.append(found)
    cap.release()
    if size is None:
        raise AbsScaleError(f'{args.video}: no frames could be read')
    result = calibration.calibrate(corners, size, cfg)
    Path(args.out).write_text(calibration.model_to_yaml(result.model, args.name))
    K = result.model.K
    print(f'board found in {len(corners)} of {index} frames; {result.views} views used; '
          f'RMS {result.rms_px:.3f} px; fx {K[0, 0]:.1f} fy {K[1, 1]:.1f} '
          f'cx {K[0, 2]:.1f} cy {K[1, 2]:.1f}; wrote {args.out}')
    return 0
