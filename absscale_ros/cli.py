"""
The ``absscale`` command: one verb per tool module under ``absscale_ros.tools``.

Each tool module defines ``add_arguments(parser)`` and ``run(args) -> int``. Modules are
imported only when their verb is used, so ``absscale bag info`` does not load GTSAM.
"""
import argparse
import importlib
import logging
import sys

from absscale_ros.core.errors import AbsScaleError

# verb path -> (module, one-line help). Add a line here when a tool is added.
COMMANDS: dict[tuple[str, ...], tuple[str, str]] = {
    ('run',): ('absscale_ros.tools.run', 'replay a bag through the node graph, write outputs'),
    ('demo',): ('absscale_ros.tools.demo', 'run the graph on the sample bag in bags/'),
    ('calibrate',): ('absscale_ros.tools.calibrate', 'camera calibration YAML from a '
                     'chessboard video'),
    ('bag', 'info'): ('absscale_ros.tools.bag_info', 'topics, types, counts, image sizes'),
    ('bench', 'replay'): ('absscale_ros.tools.bench_replay', 'bag_replay step-mode throughput'),
    ('simulate',): ('absscale_ros.tools.simulate', 'render a handheld video with ground truth'),
    ('bench', 'render'): ('absscale_ros.tools.bench_render', 'simulator rendering speed'),
    ('bench', 'scale'): ('absscale_ros.tools.bench_scale', 'metric scale and lengths against '
                         'ground truth (Table 3)'),
    ('detect',): ('absscale_ros.tools.detect', 'detect target vertices in image files'),
    ('bench', 'detect'): ('absscale_ros.tools.bench_detect', 'detection accuracy against gt.json'),
    ('bench', 'sfm'): ('absscale_ros.tools.bench_sfm', 'SfM against gt.json and pycolmap'),
    ('bench', 'keyframes'): ('absscale_ros.tools.bench_keyframes', 'keyframes against gt.json'),
    ('bench', 'dense'): ('absscale_ros.tools.bench_dense', 'dense cloud against gt.json'),
}


def _usage() -> str:
    lines = ['usage: absscale COMMAND [...]', '', 'commands:']
    for path, (module, text) in COMMANDS.items():
        if importlib.util.find_spec(module) is not None:
            lines.append(f'  {" ".join(path):<16} {text}')
    return '\n'.join(lines)


def _find(argv: list[str]) -> tuple[tuple[str, ...], list[str]] | None:
    for n in (2, 1):
        path = tuple(argv[:n])
        if path in COMMANDS:
            return path, argv[n:]
    return None


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    found = _find(argv)
    if found is None:
        asked = bool(argv) and argv[0] in ('-h', '--help')
        print(_usage(), file=sys.stdout if asked else sys.stderr)
        return 0 if asked else 2
    path, rest = found
    module_name, text = COMMANDS[path]
    module = importlib.import_module(module_name)
    parser = argparse.ArgumentParser(prog='absscale ' + ' '.join(path), description=text)
    parser.add_argument('-v', '--verbose', action='store_true', help='debug logging')
    module.add_arguments(parser)
    args = parser.parse_args(rest)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format='%(levelname)s %(name)s: %(message)s')
    try:
        return int(module.run(args))
    except AbsScaleError as err:  # expected failures: one line, no traceback
        print(f'absscale {" ".join(path)}: error: {err}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == '__main__':
    sys.exit(main())
